// Batch decoder F(x, y, omega_i, omega_v): one work-item per query, the same steps as
// Decoder::evaluate (pipeline/decoder.cpp) and FORMAT.md "Decoding one value". Arithmetic is in
// double where the device has it, so that the kernel and its C++ reference agree closely even near
// the pole of the onion parametrization, where alpha is ill-conditioned.
#ifdef cl_khr_fp64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
#else
typedef float real;
#endif

#define DEG ((real)0.017453292519943295)

real wrap360(real a) {
  a = fmod(a, (real)360);
  return a < 0 ? a + (real)360 : a;
}

real asin_deg(real x) { return asin(clamp(x, (real)-1, (real)1)) / DEG; }

real beta_node(int k, int nb) { return asin_deg((real)-1 + (real)2 * (real)k / (real)(nb - 1)); }

// Coding space (L, a, b) -> RGB: BT.601 studio-swing inverse for LDR, LogLuv for HDR (pipeline/colour.cpp).
float3 from_coding_space(float l, float a, float b, int hdr) {
  if (!hdr) {
    const float r = 1.1643828f * l + 1.5960273f * b - 222.921f;
    const float g = 1.1643828f * l - 0.39176172f * a - 0.81296875f * b + 135.576f;
    const float bb = 1.1643828f * l + 2.0172344f * a - 276.836f;
    return (float3)(fmax(r, 0.0f), fmax(g, 0.0f), fmax(bb, 0.0f));
  }
  const float y = fmax(l, 0.0f);
  if (y <= 1e-12f) return (float3)(0.0f, 0.0f, 0.0f);
  const float Y = exp2(log2(y));
  const float u = a / 255.0f;
  const float v = fmax(b / 255.0f, 1e-6f);
  const float X = Y * 9.0f * u / (4.0f * v);
  const float Z = Y * (12.0f - 3.0f * u - 20.0f * v) / (4.0f * v);
  return (float3)(3.2404542f * X - 1.5371385f * Y - 0.4985314f * Z, -0.9692660f * X + 1.8760108f * Y + 0.0415560f * Z,
                  0.0556434f * X - 0.2040259f * Y + 1.0572252f * Z);
}

__kernel void decode_batch(__global const float* p1, __global const float* c, __global const uint* i1,
                           __global const uint* i2, __global const uint* p2_index, __global const float* p2_scale,
                           __global const uint* m, __global const uint* p3_index, __global const float* p3_scale,
                           __global const uint* p4_index, __global const float* p4_scale, __global const int* p6_index,
                           __global const float* p6_scale, __global const int* materials, const int nb, const int na,
                           const int nt, const int np, __global const int* texels, __global const float* angles,
                           __global float* out, const uint n) {
  const uint q = get_global_id(0);
  if (q >= n) return;
  out[q * 3 + 0] = 0.0f;
  out[q * 3 + 1] = 0.0f;
  out[q * 3 + 2] = 0.0f;
  const real theta_i = angles[q * 4 + 0], phi_i = angles[q * 4 + 1];
  const real theta_v = angles[q * 4 + 2], phi_v = angles[q * 4 + 3];
  if (!(theta_i <= (real)90 && theta_v <= (real)90) || !isfinite(phi_i) || !isfinite(phi_v)) return;

  // P6: texel indices wrap modulo the material size; -1 = not compressed.
  const int mat = texels[q * 4 + 0];
  const int offset = materials[mat * 4 + 0], width = materials[mat * 4 + 1], height = materials[mat * 4 + 2];
  const int hdr = materials[mat * 4 + 3];
  if (width <= 0 || height <= 0) return;
  int x = texels[q * 4 + 1] % width, y = texels[q * 4 + 2] % height;
  if (x < 0) x += width;
  if (y < 0) y += height;
  const int texel = offset + y * width + x;
  const int p4_row = p6_index[texel];
  if (p4_row < 0) return;

  // Onion angles of the light for this view azimuth.
  const real p = wrap360(phi_i - phi_v - (real)90) * DEG, t = theta_i * DEG;
  const real sb = clamp(cos(p) * sin(t), (real)-1, (real)1), ly = sin(p) * sin(t);
  const real beta = asin_deg(sb);
  const real cbeta = sqrt((real)1 - sb * sb);  // cos(beta), as Decoder::evaluate computes it
  const real alpha = cbeta > 0 ? asin_deg(ly / cbeta) : (real)0;

  // Cells.
  const int bi = clamp((int)floor((sb + (real)1) / (real)2 * (real)(nb - 1)), 0, nb - 2);
  const real b0 = beta_node(bi, nb), b1 = beta_node(bi + 1, nb);
  const real bw = clamp((beta - b0) / (b1 - b0), (real)0, (real)1);
  const real astep = (real)180 / (real)(na - 1);
  const int ai = clamp((int)floor((alpha + (real)90) / astep), 0, na - 2);
  const real aw = clamp((alpha - ((real)-90 + (real)ai * astep)) / astep, (real)0, (real)1);
  const real tstep = (real)90 / (real)(nt - 1);
  int ti0 = max(0, (int)floor(theta_v / tstep)), ti1;
  real tw;
  if (ti0 >= nt - 1) {
    ti0 = nt - 1;
    ti1 = nt - 1;
    tw = 0;
  } else {
    ti1 = ti0 + 1;
    tw = clamp((theta_v - (real)ti0 * tstep) / tstep, (real)0, (real)1);
  }
  const real pstep = (real)360 / (real)np;
  const real pv = wrap360(phi_v);
  const int pi0 = clamp((int)floor(pv / pstep), 0, np - 1);
  const int pi1 = (pi0 + 1) % np;
  const real pw = clamp((pv - (real)pi0 * pstep) / pstep, (real)0, (real)1);

  // Cubic Hermite weights along beta (FORMAT.md step 4).
  const real h01 = -2 * bw * bw * bw + 3 * bw * bw;
  const real h00 = 1 - h01;
  const real h11 = bw * bw * bw - bw * bw;
  const real h10 = h11 - bw * bw + bw;
  const int first = bi == 0, last = bi == nb - 2;

  const int phi_node[2] = {pi0, pi1};
  const real phi_w[2] = {1 - pw, pw};
  const int theta_node[2] = {ti0, ti1};
  const real theta_w[2] = {ti0 == ti1 ? (real)1 : 1 - tw, ti0 == ti1 ? (real)0 : tw};
  const int alpha_node[2] = {ai, ai + 1};
  const real alpha_w[2] = {1 - aw, aw};

  real r = 0, g = 0, b = 0;
  for (int pp = 0; pp < 2; ++pp) {
    if (phi_w[pp] == 0) continue;
    const int p3_row = (int)p4_index[p4_row * np + phi_node[pp]];
    const real s4 = phi_w[pp] * (real)p4_scale[p4_row * np + phi_node[pp]];
    for (int tt = 0; tt < 2; ++tt) {
      if (theta_w[tt] == 0) continue;
      const int tn = theta_node[tt];
      const real s = s4 * theta_w[tt] * (real)p3_scale[p3_row * nt + tn];
      const uint mi = p3_index[p3_row * nt + tn];
      const uint p2 = m[mi * 2 + 0], ii2 = m[mi * 2 + 1];
      real yy = 0, cb = 0, cr = 0;
      for (int a = 0; a < 2; ++a) {
        const int an = alpha_node[a];
        const real w = alpha_w[a];
        __global const float* sl = p1 + (size_t)p2_index[p2 * na + an] * nb;
        const real q0 = sl[bi], q1 = sl[bi + 1];
        const real m0 = first ? q1 - q0 : (q1 - (real)sl[bi - 1]) / 2;
        const real m1 = last ? q1 - q0 : ((real)sl[bi + 1] - q0) / 2;
        yy += w * (real)p2_scale[p2 * na + an] * (h00 * q0 + h10 * m0 + h01 * q1 + h11 * m1);
        __global const uint* row1 = i1 + (size_t)i2[ii2 * na + an] * nb;
        const uint c0 = row1[bi], c1 = row1[bi + 1];
        cb += w * ((1 - bw) * (real)c[c0 * 2] + bw * (real)c[c1 * 2]);
        cr += w * ((1 - bw) * (real)c[c0 * 2 + 1] + bw * (real)c[c1 * 2 + 1]);
      }
      const float3 v = from_coding_space((float)yy, (float)cb, (float)cr, hdr);
      r += s * (real)v.x;
      g += s * (real)v.y;
      b += s * (real)v.z;
    }
  }
  const real s6 = p6_scale[texel];
  out[q * 3 + 0] = (float)(r * s6);
  out[q * 3 + 1] = (float)(g * s6);
  out[q * 3 + 2] = (float)(b * s6);
}
