// Batch decoder F(x, y, omega_i, omega_v): the same steps as Decoder::evaluate (pipeline/decode/decoder.cpp)
// and docs/btfbase-format.md "Decoding one value", in 32-bit floats, DECODE_WIDTH queries per work-item.
//
// Why float is enough: every interpolation is continuous across cell boundaries, and the one
// ill-conditioned step of the reference (alpha = asin(y / cos(beta)) near the pole of the onion
// parametrization) is computed here in a well-conditioned form: with the light at (theta, phi')
//   sin(beta) = cos(phi') sin(theta), cos(beta) = sqrt(cos^2(theta) + (sin(phi') sin(theta))^2),
//   alpha = atan2(sin(phi') sin(theta), cos(theta)),  beta = atan2(sin(beta), cos(beta)),
// which are the same angles (docs/btfbase-format.md step 2) without cancellation.
//
// Why explicit vectors: PoCL's CPU device vectorizes a work-group only when LLVM's loop vectorizer
// accepts the whole kernel, and on a kernel of this size its SLP pass runs first and makes that
// impossible (measured: ~4 M queries per CPU second, scalar). So each work-item decodes
// DECODE_WIDTH queries as one SIMD vector (AVX-512: 16 floats), the code-book look-ups are written
// lane by lane, and there are no branches on the data: a query that is not decodable takes the
// same path with valid indices and is multiplied by zero at the end. Sine, cosine and arc tangent
// are small polynomials (Cephes), not the library's per-element calls.

#define DECODE_WIDTH 16
typedef float16 floatv;
typedef int16 intv;
#define VLOADF vload16
#define VLOADI vload16
#define VSTOREF vstore16
#define CONVERT_INT convert_int16
#define CONVERT_FLOAT convert_float16
// A look-up of one table entry per lane.
#define GATHER(T, p, i)                                                                                       \
  ((T)(p[(i).s0], p[(i).s1], p[(i).s2], p[(i).s3], p[(i).s4], p[(i).s5], p[(i).s6], p[(i).s7], p[(i).s8],  \
       p[(i).s9], p[(i).sa], p[(i).sb], p[(i).sc], p[(i).sd], p[(i).se], p[(i).sf]))
#define GATHERF(p, i) GATHER(floatv, p, i)
#define GATHERI(p, i) GATHER(intv, p, i)

#define RAD_PER_DEG 0.017453292519943295f
#define DEG_PER_RAD 57.29577951308232f

// Lanes where the int mask m is true (-1) take a, the others b.
floatv pick(intv m, floatv a, floatv b) { return select(b, a, m); }
intv pick_i(intv m, intv a, intv b) { return select(b, a, m); }
intv clamp_i(intv x, int lo, int hi) { return min(max(x, (intv)lo), (intv)hi); }

// sin and cos of an angle in degrees (|d| <= 360): reduction to [-45, 45] around the nearest multiple of 90,
// then the Cephes polynomials; quadrant k gives (s, c), (c, -s), (-s, -c), (-c, s).
void sincos_deg(floatv d, floatv* sin_d, floatv* cos_d) {
  const floatv k = floor(d / 90.0f + 0.5f);
  const floatv x = (d - 90.0f * k) * RAD_PER_DEG;
  const floatv z = x * x;
  const floatv s = ((-1.9515295891e-4f * z + 8.3321608736e-3f) * z - 1.6666654611e-1f) * z * x + x;
  const floatv c = ((2.443315711809948e-5f * z - 1.388731625493765e-3f) * z + 4.166664568298827e-2f) * z * z - 0.5f * z + 1.0f;
  const intv quadrant = CONVERT_INT(k) & 3;
  const intv odd = (quadrant & 1) != 0;
  const floatv sa = pick(odd, c, s), ca = pick(odd, s, c);
  *sin_d = pick((quadrant & 2) != 0, -sa, sa);
  *cos_d = pick(((quadrant + 1) & 2) != 0, -ca, ca);
}

// atan2(y, x) in degrees for x >= 0 (Cephes atanf with its reduction by tan(pi/8)); 0 when both are 0.
floatv atan_deg(floatv y, floatv x) {
  const floatv ay = fabs(y);
  const floatv big = fmax(ay, x), small = fmin(ay, x);
  floatv r = pick(big > 0.0f, small / big, (floatv)0.0f);  // in [0, 1]
  const intv reduce = r > 0.41421356f;
  r = pick(reduce, (r - 1.0f) / (r + 1.0f), r);
  const floatv z = r * r;
  floatv a = (((8.05374449538e-2f * z - 1.38776856032e-1f) * z + 1.99777106478e-1f) * z - 3.33329491539e-1f) * z * r + r;
  a = pick(reduce, (floatv)45.0f, (floatv)0.0f) + a * DEG_PER_RAD;
  a = pick(ay > x, 90.0f - a, a);
  return copysign(a, y);
}

floatv wrap360(floatv a) { return a - 360.0f * floor(a / 360.0f); }
// Into [-180, 180): a small angle stays exact (wrapping -0.01 to 359.99 would keep only three
// significant digits of it, and the light azimuth near the pole needs them all).
floatv wrap180(floatv a) { return a - 360.0f * floor(a / 360.0f + 0.5f); }

// Position of x in a grid of nodes 0, step, 2 step, ... clamped to cell [0, last_cell]: the cell and
// the weight of its second node.
intv cell_of(floatv x, float step, int last_cell, floatv* w) {
  const floatv cells = x * (1.0f / step);
  const intv i = clamp_i(CONVERT_INT(floor(cells)), 0, last_cell);
  *w = clamp(cells - CONVERT_FLOAT(i), 0.0f, 1.0f);
  return i;
}

// Coding space (L, a, b) -> RGB, added with weight w to (r, g, b): BT.601 studio-swing inverse for
// LDR, LogLuv for HDR (pipeline/colour.cpp).
void add_rgb(floatv l, floatv a, floatv b, intv hdr, floatv w, floatv* r, floatv* g, floatv* bl) {
  const floatv lr = fmax(1.1643828f * l + 1.5960273f * b - 222.921f, 0.0f);
  const floatv lg = fmax(1.1643828f * l - 0.39176172f * a - 0.81296875f * b + 135.576f, 0.0f);
  const floatv lb = fmax(1.1643828f * l + 2.0172344f * a - 276.836f, 0.0f);
  const floatv Y = fmax(l, 0.0f);
  const floatv u = a * (1.0f / 255.0f);
  const floatv v = fmax(b * (1.0f / 255.0f), 1e-6f);
  const floatv y_4v = Y / (4.0f * v);  // one division: they are the slowest vector instruction here
  const floatv X = 9.0f * u * y_4v;
  const floatv Z = (12.0f - 3.0f * u - 20.0f * v) * y_4v;
  const intv lit = Y > 1e-12f;
  const intv use_hdr = hdr != 0;
  const floatv hr = pick(lit, 3.2404542f * X - 1.5371385f * Y - 0.4985314f * Z, (floatv)0.0f);
  const floatv hg = pick(lit, -0.9692660f * X + 1.8760108f * Y + 0.0415560f * Z, (floatv)0.0f);
  const floatv hb = pick(lit, 0.0556434f * X - 0.2040259f * Y + 1.0572252f * Z, (floatv)0.0f);
  *r += w * pick(use_hdr, hr, lr);
  *g += w * pick(use_hdr, hg, lg);
  *bl += w * pick(use_hdr, hb, lb);
}

// P2, P3, P4 and P6 arrive as (index, scale) pairs, one look-up touching one cache line: each is
// bound twice, as X_index (ints) and as X_scale (floats), entry i at 2 i and 2 i + 1.
// Queries, one array per field, DECODE_WIDTH x the global size long: texel = 2 x (index into the
// concatenated P6 of all materials) + hdr, or -1 when the query decodes to zero for a reason known
// on the host (empty material, padding); angles in degrees. Results: three planes r, g, b of n
// values each (n = DECODE_WIDTH x the global size).
__kernel void decode_batch(__global const float* p1, __global const float* c, __global const int* i1,
                           __global const int* i2, __global const int* p2_index, __global const float* p2_scale,
                           __global const int* m, __global const int* p3_index, __global const float* p3_scale,
                           __global const int* p4_index, __global const float* p4_scale, __global const int* p6_index,
                           __global const float* p6_scale, __global const float* beta_nodes, const int nb,
                           const int na, const int nt, const int np, __global const int* texels,
                           __global const float* theta_i_in, __global const float* phi_i_in,
                           __global const float* theta_v_in, __global const float* phi_v_in, __global float* out,
                           const uint n) {
  const size_t g = get_global_id(0);
  const floatv ti_in = VLOADF(g, theta_i_in), pi_in = VLOADF(g, phi_i_in);
  const floatv tv_in = VLOADF(g, theta_v_in), pv_in = VLOADF(g, phi_v_in);
  const intv code = VLOADI(g, texels);
  intv valid = (ti_in <= 90.0f) & (tv_in <= 90.0f) & (fabs(pi_in) <= MAXFLOAT) & (fabs(pv_in) <= MAXFLOAT) & (code >= 0);
  // An undecodable query continues with harmless inputs (no NaN reaches an index computation).
  const floatv zero = 0.0f;
  const floatv theta_i = pick(valid, ti_in, zero), theta_v = pick(valid, tv_in, zero);
  const floatv phi_v = pick(valid, wrap360(pv_in), zero);
  const floatv light_azimuth = pick(valid, wrap180(pi_in - pv_in - 90.0f), zero);  // phi' of docs/btfbase-format.md step 1
  const intv texel = pick_i(valid, code >> 1, (intv)0), hdr = code & 1;
  const intv p6 = GATHERI(p6_index, 2 * texel);
  valid &= p6 >= 0;
  const intv p4_row = max(p6, (intv)0);

  // Onion angles of the light for this view azimuth (see the top of the file).
  floatv sin_t, cos_t, sin_p, cos_p;
  sincos_deg(theta_i, &sin_t, &cos_t);
  sincos_deg(light_azimuth, &sin_p, &cos_p);
  const floatv sb = clamp(cos_p * sin_t, -1.0f, 1.0f), ly = sin_p * sin_t;
  const floatv beta = atan_deg(sb, sqrt(cos_t * cos_t + ly * ly));
  const floatv alpha = atan_deg(ly, cos_t);

  // Cells. Beta nodes are uniform in sin(beta); the weight is linear in degrees inside the cell.
  const intv bi = clamp_i(CONVERT_INT(floor((sb + 1.0f) * 0.5f * (float)(nb - 1))), 0, nb - 2);
  const floatv b0 = GATHERF(beta_nodes, bi), b1 = GATHERF(beta_nodes, bi + 1);
  const floatv bw = clamp((beta - b0) / (b1 - b0), 0.0f, 1.0f);
  floatv aw, tw, pw;
  const intv ai = cell_of(alpha + 90.0f, 180.0f / (float)(na - 1), na - 2, &aw);
  // At or beyond the last theta_v node only that node is used: there the weight of the cell's
  // second node (the last one) is 1.
  const intv ti = cell_of(theta_v, 90.0f / (float)(nt - 1), nt - 2, &tw);
  const intv pi0 = cell_of(phi_v, 360.0f / (float)np, np - 1, &pw);
  const intv pi1 = pick_i(pi0 + 1 == np, (intv)0, pi0 + 1);

  // Cubic Hermite along beta (docs/btfbase-format.md step 4), folded with the tangents into one weight per P1
  // sample: value = h00 p0 + h10 m0 + h01 p1 + h11 m1 with m0 = p1 - p0 (first cell) or
  // (p1 - s[i-1]) / 2, m1 = p1 - p0 (last cell) or (s[i+1] - p0) / 2 = (p1 - p0) / 2 (sic).
  const floatv h01 = -2.0f * bw * bw * bw + 3.0f * bw * bw;
  const floatv h00 = 1.0f - h01;
  const floatv h11 = bw * bw * bw - bw * bw;
  const floatv h10 = h11 - bw * bw + bw;
  const intv first = bi == 0, last = bi == nb - 2;
  const floatv wm = pick(first, zero, -0.5f * h10);
  const floatv w0 = h00 - pick(first, h10, zero) - pick(last, h11, 0.5f * h11);
  const floatv w1 = h01 + pick(first, h10, 0.5f * h10) + pick(last, h11, 0.5f * h11);
  const intv sm = pick_i(first, bi, bi - 1);

  // The code-book chain is followed level by level for the four (phi_v, theta_v) nodes and both
  // alpha nodes at once: the look-ups of one level are independent, so their memory latencies
  // overlap instead of adding up (for random queries the tables are mostly not in cache).
  // docs/btfbase-format.md step 6: P4 over phi_v (nodes pi0, pi1), P3 over theta_v (nodes ti, ti + 1), each node
  // with its scale; entry e = 2 x phi node + theta node.
  const intv p4a = p4_row * np + pi0, p4b = p4_row * np + pi1;
  const intv p3a = GATHERI(p4_index, 2 * p4a) * nt + ti, p3b = GATHERI(p4_index, 2 * p4b) * nt + ti;
  const floatv sa = (1.0f - pw) * GATHERF(p4_scale, 2 * p4a + 1), sb4 = pw * GATHERF(p4_scale, 2 * p4b + 1);
  // (Each level is written out per entry with macros: private arrays would make PoCL keep a copy
  // per work-item of the group on the stack.)
#define M_ENTRY(e, p3e, node_w)                          \
  const intv mi##e = 2 * GATHERI(p3_index, 2 * (p3e)); \
  const floatv entry_w##e = (node_w) * GATHERF(p3_scale, 2 * (p3e) + 1);
  M_ENTRY(0, p3a, sa * (1.0f - tw))
  M_ENTRY(1, p3a + 1, sa * tw)
  M_ENTRY(2, p3b, sb4 * (1.0f - tw))
  M_ENTRY(3, p3b + 1, sb4 * tw)
  // Step 5: M -> (P2 row, I2 row) -> per alpha node (P1 row, P2 scale) and I1 row -> P1 samples and C.
#define M_ROWS(e)                                           \
  const intv p2_row##e = GATHERI(m, mi##e) * na + ai;       \
  const intv i2_row##e = GATHERI(m, mi##e + 1) * na + ai;
  M_ROWS(0) M_ROWS(1) M_ROWS(2) M_ROWS(3)
#define ALPHA_ROWS(e, a)                                       \
  const intv p1_row##e##a = GATHERI(p2_index, 2 * (p2_row##e + a)) * nb; \
  const floatv p2s##e##a = GATHERF(p2_scale, 2 * (p2_row##e + a) + 1); \
  const intv i1_row##e##a = GATHERI(i2, i2_row##e + a) * nb;
  ALPHA_ROWS(0, 0) ALPHA_ROWS(0, 1) ALPHA_ROWS(1, 0) ALPHA_ROWS(1, 1)
  ALPHA_ROWS(2, 0) ALPHA_ROWS(2, 1) ALPHA_ROWS(3, 0) ALPHA_ROWS(3, 1)
#define ALPHA_SAMPLES(e, a)                                                                                  \
  const intv c0_##e##a = 2 * GATHERI(i1, i1_row##e##a + bi), c1_##e##a = 2 * GATHERI(i1, i1_row##e##a + bi + 1); \
  const floatv luma##e##a = p2s##e##a * (wm * GATHERF(p1, p1_row##e##a + sm) + w0 * GATHERF(p1, p1_row##e##a + bi) + \
                                         w1 * GATHERF(p1, p1_row##e##a + bi + 1));
  ALPHA_SAMPLES(0, 0) ALPHA_SAMPLES(0, 1) ALPHA_SAMPLES(1, 0) ALPHA_SAMPLES(1, 1)
  ALPHA_SAMPLES(2, 0) ALPHA_SAMPLES(2, 1) ALPHA_SAMPLES(3, 0) ALPHA_SAMPLES(3, 1)
  // Chroma of one alpha node: linear in beta over C(I1).
#define CHROMA(e, a, ch) ((1.0f - bw) * GATHERF(c, c0_##e##a + ch) + bw * GATHERF(c, c1_##e##a + ch))
#define ADD_M_ENTRY(e)                                                                                  \
  add_rgb((1.0f - aw) * luma##e##0 + aw * luma##e##1, (1.0f - aw) * CHROMA(e, 0, 0) + aw * CHROMA(e, 1, 0), \
          (1.0f - aw) * CHROMA(e, 0, 1) + aw * CHROMA(e, 1, 1), hdr, entry_w##e, &r, &gr, &b);
  floatv r = 0.0f, gr = 0.0f, b = 0.0f;
  ADD_M_ENTRY(0) ADD_M_ENTRY(1) ADD_M_ENTRY(2) ADD_M_ENTRY(3)

  const floatv s6 = pick(valid, GATHERF(p6_scale, 2 * texel + 1), zero);
  VSTOREF(r * s6, g, out);
  VSTOREF(gr * s6, g, out + n);
  VSTOREF(b * s6, g, out + 2 * n);
}
