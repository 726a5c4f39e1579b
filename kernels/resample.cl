// RBF resampling of measured texels onto the (phi_v, theta_v, alpha, beta) grid as a fixed sparse
// operator (pipeline/encode/resample.h; C++ reference: ResampleOperator::apply_reference).
//
// Every work-item handles an "octet" of 8 neighbouring texels with explicit float8 arithmetic (a CPU
// compiler vectorises inner loops, not the work-item loop around them), and each octet's data is
// one contiguous block, so that a work-item's gathers stay inside a cache-sized block:
//   lab    [octet][pair][channel][8]
//   slots  [octet][slot row][channel][8]     (slot row = slot * n_ab + alpha * n_beta + beta)
//   out    [texel][channel][node]            (the caller's layout, node = AngularGrid::index)

typedef struct {
  uint index;
  float weight;
} SparseEntry;

// Gathers the RGB of pair p for the texels t .. t+7 (those below n) into float8 r, g, b; a full octet
// is unrolled so that the lanes are registers, not memory.
#define LOAD_OCTET(T)                                                         \
  __global const T* v0 = rgb + ((size_t)t * pairs + p) * 3;                   \
  const size_t stride = (size_t)pairs * 3;                                    \
  if (t + 8 <= n) {                                                           \
    const float3 c0 = convert_float3(vload3(0, v0));                          \
    const float3 c1 = convert_float3(vload3(0, v0 + stride));                 \
    const float3 c2 = convert_float3(vload3(0, v0 + 2 * stride));             \
    const float3 c3 = convert_float3(vload3(0, v0 + 3 * stride));             \
    const float3 c4 = convert_float3(vload3(0, v0 + 4 * stride));             \
    const float3 c5 = convert_float3(vload3(0, v0 + 5 * stride));             \
    const float3 c6 = convert_float3(vload3(0, v0 + 6 * stride));             \
    const float3 c7 = convert_float3(vload3(0, v0 + 7 * stride));             \
    r = (float8)(c0.x, c1.x, c2.x, c3.x, c4.x, c5.x, c6.x, c7.x);             \
    g = (float8)(c0.y, c1.y, c2.y, c3.y, c4.y, c5.y, c6.y, c7.y);             \
    b = (float8)(c0.z, c1.z, c2.z, c3.z, c4.z, c5.z, c6.z, c7.z);             \
  } else {                                                                    \
    float lr[8] = {0}, lg[8] = {0}, lb[8] = {0};                              \
    for (uint k = 0; t + k < n; ++k) {                                        \
      lr[k] = v0[k * stride];                                                 \
      lg[k] = v0[k * stride + 1];                                             \
      lb[k] = v0[k * stride + 2];                                             \
    }                                                                         \
    r = vload8(0, lr);                                                        \
    g = vload8(0, lg);                                                        \
    b = vload8(0, lb);                                                        \
  }

// BT.601 studio-swing YCbCr of gamma-encoded 8-bit RGB (colour.cpp rgb_to_ycbcr); texels past n
// become zero so that padded lanes stay finite.
__kernel void convert_ldr(__global const uchar* rgb, __global float* lab, const uint n, const uint pairs) {
  const uint p = get_global_id(0), t = get_global_id(1) * 8;
  float8 r = 0.0f, g = 0.0f, b = 0.0f;
  LOAD_OCTET(uchar)
  __global float* dst = lab + ((size_t)t * pairs + (size_t)p * 8) * 3;
  vstore8(16.0f + (65.481f * r + 128.553f * g + 24.966f * b) / 255.0f, 0, dst);
  vstore8(128.0f + (-37.797f * r - 74.203f * g + 112.0f * b) / 255.0f, 0, dst + 8);
  vstore8(128.0f + (112.0f * r - 93.786f * g - 18.214f * b) / 255.0f, 0, dst + 16);
}

// Linear Y and 255 (u', v') of linear Rec. 709 RGB (colour.cpp to_coding_space, HDR).
__kernel void convert_hdr(__global const float* rgb, __global float* lab, const uint n, const uint pairs) {
  const uint p = get_global_id(0), t = get_global_id(1) * 8;
  float8 r = 0.0f, g = 0.0f, b = 0.0f;
  LOAD_OCTET(float)
  const float8 X = 0.4124564f * r + 0.3575761f * g + 0.1804375f * b;
  const float8 Y = 0.2126729f * r + 0.7151522f * g + 0.0721750f * b;
  const float8 Z = 0.0193339f * r + 0.1191920f * g + 0.9503041f * b;
  const float8 d = X + 15.0f * Y + 3.0f * Z;
  const int8 black = isless(Y, (float8)1e-12f) | isequal(Y, (float8)1e-12f) | islessequal(d, (float8)0.0f);
  const float8 safe_d = select(d, (float8)1.0f, black);
  __global float* dst = lab + ((size_t)t * pairs + (size_t)p * 8) * 3;
  vstore8(select(Y, (float8)1e-12f, black), 0, dst);
  vstore8(255.0f * select(4.0f * X / safe_d, (float8)0.197839f, black), 0, dst + 8);
  vstore8(255.0f * select(9.0f * Y / safe_d, (float8)0.468342f, black), 0, dst + 16);
}

// Light step: one work-item per (slot, octet), looping over the slot's n_ab rows.
__kernel void light_step(__global const float* lab, __global const SparseEntry* rows, const uint width,
                         const uint n_ab, const uint pairs, const uint slot_count, __global float* slots) {
  const uint slot = get_global_id(0), octet = get_global_id(1);
  __global const float* src = lab + (size_t)octet * pairs * 24;
  __global float* dst = slots + ((size_t)octet * slot_count + slot) * n_ab * 24;
  __global const SparseEntry* row = rows + (size_t)slot * n_ab * width;
  for (uint ab = 0; ab < n_ab; ++ab, row += width, dst += 24) {
    float8 l = 0.0f, a = 0.0f, b = 0.0f;
    for (uint j = 0; j < width; ++j) {
      const SparseEntry e = row[j];
      __global const float* v = src + (size_t)e.index * 24;
      l += e.weight * vload8(0, v);
      a += e.weight * vload8(1, v);
      b += e.weight * vload8(2, v);
    }
    vstore8(l, 0, dst);
    vstore8(a, 1, dst);
    vstore8(b, 2, dst);
  }
}

// View step: one work-item per (output view node, octet), looping over the node's (alpha, beta)
// samples, so each texel's outputs are written as contiguous runs. Luminance clamped at 0.
__kernel void view_step(__global const float* slots, __global const SparseEntry* rows, const uint width,
                        const uint n_ab, const uint slot_count, const uint n, const uint samples,
                        __global float* out) {
  const uint view_node = get_global_id(0), octet = get_global_id(1), t = octet * 8;
  __global const float* src = slots + (size_t)octet * slot_count * n_ab * 24;
  __global const SparseEntry* row = rows + (size_t)view_node * width;
  const uint lanes = min(8u, n - t);
  __global float* dst = out + (size_t)t * 3 * samples + (size_t)view_node * n_ab;
  for (uint ab = 0; ab < n_ab; ++ab) {
    float8 l = 0.0f, a = 0.0f, b = 0.0f;
    for (uint i = 0; i < width; ++i) {
      const SparseEntry e = row[i];
      __global const float* v = src + ((size_t)e.index * n_ab + ab) * 24;
      l += e.weight * vload8(0, v);
      a += e.weight * vload8(1, v);
      b += e.weight * vload8(2, v);
    }
    l = fmax(l, 0.0f);
    __global float* o = dst + ab;
    if (lanes == 8) {
      const size_t k = 3 * (size_t)samples;
      o[0] = l.s0, o[samples] = a.s0, o[2 * samples] = b.s0, o += k;
      o[0] = l.s1, o[samples] = a.s1, o[2 * samples] = b.s1, o += k;
      o[0] = l.s2, o[samples] = a.s2, o[2 * samples] = b.s2, o += k;
      o[0] = l.s3, o[samples] = a.s3, o[2 * samples] = b.s3, o += k;
      o[0] = l.s4, o[samples] = a.s4, o[2 * samples] = b.s4, o += k;
      o[0] = l.s5, o[samples] = a.s5, o[2 * samples] = b.s5, o += k;
      o[0] = l.s6, o[samples] = a.s6, o[2 * samples] = b.s6, o += k;
      o[0] = l.s7, o[samples] = a.s7, o[2 * samples] = b.s7;
    } else {
      float ls[8], as[8], bs[8];
      vstore8(l, 0, ls);
      vstore8(a, 0, as);
      vstore8(b, 0, bs);
      for (uint k = 0; k < lanes; ++k, o += 3 * (size_t)samples) {
        o[0] = ls[k];
        o[samples] = as[k];
        o[2 * samples] = bs[k];
      }
    }
  }
}
