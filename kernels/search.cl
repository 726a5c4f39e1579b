// Batched phase-3 search (pipeline/frozen_search.h, docs/similarity.md "Batched search").
//
// One work-item scores one (texel, P4 candidate) pair: the candidate's best RGB scale (least squares
// on the offset-removed values), then every SSIM value of the texel against the scaled candidate,
// counted into a histogram of SEARCH_BINS bins over [0, 1]. It returns the bin that holds the
// (keep)-th smallest value, i.e. a bracket around the candidate's SSIM-percentile score; the host
// settles the few candidates whose brackets reach the best one exactly (Encoder::encode_frozen_among),
// so the chosen entry is exactly the pruned search's. No early abandonment here: every candidate
// does the same work, which is what vectorizes across work-items.
//
// Like kernels/synthetic.cl, this text is also the C++ reference (pipeline/frozen_search.cpp
// includes it with a small prelude), so it sticks to the C subset both languages share.
//
// Layouts (n = rows x cols samples of one (theta_v, phi_v) plane, planes = n_phi_v x n_theta_v):
//   query   per texel: [plane][channel 0..2][values | window means | window variances][n]
//   consts  per texel: c1[3], c2[3]
//   lum     per P2 entry: [values | means | variances][n]   (SliceStore blocks)
//   chroma  per I2 entry: [values a, b | means a, b | variances a, b][n]
//   plane_* per P4 entry: its planes' P2 entry, I2 entry and scale factor (P4 x P3 scale)

#define SEARCH_BINS 512

float search_offset(int hdr, int c) { return hdr ? 0.0f : (c == 0 ? 16.0f : 128.0f); }
int search_scales(int hdr, int c) { return !hdr || c == 0; }

// Where the candidate's values of plane channel c live.
__global const float* search_entry(__global const float* lum, __global const float* chroma, unsigned p2,
                                   unsigned i2, int c, int n) {
  return c == 0 ? lum + (long)p2 * 3 * n : chroma + (long)i2 * 6 * n + (c - 1) * n;
}

int search_bin_item(__global const float* query, __global const float* consts, __global const unsigned* plane_p2,
                    __global const unsigned* plane_i2, __global const float* plane_f, __global const float* lum,
                    __global const float* chroma, __global const float* inv_count, int rows, int cols, int radius,
                    int planes, int hdr, int keep) {
  const int n = rows * cols;
  // The least-squares scale over the channels it acts on, offset-removed before multiplying (the
  // float sums would otherwise cancel catastrophically around the chroma offset 128).
  float num = 0.0f, den = 0.0f;
  for (int j = 0; j < planes; ++j) {
    const float f = plane_f[j];
    for (int c = 0; c < 3; ++c) {
      if (!search_scales(hdr, c)) continue;
      __global const float* x = query + (long)(j * 3 + c) * 3 * n;
      __global const float* y = search_entry(lum, chroma, plane_p2[j], plane_i2[j], c, n);
      const float o = search_offset(hdr, c);
      float xy = 0.0f, yy = 0.0f;
      for (int i = 0; i < n; ++i) {
        const float yo = y[i] - o;
        xy += (x[i] - o) * yo;
        yy += yo * yo;
      }
      num += f * xy;
      den += f * f * yy;
    }
  }
  const float s = den > 1e-20f ? (num / den > 0.0f ? num / den : 0.0f) : 1.0f;

  unsigned histogram[SEARCH_BINS];
  for (int b = 0; b < SEARCH_BINS; ++b) histogram[b] = 0;
  for (int j = 0; j < planes; ++j) {
    for (int c = 0; c < 3; ++c) {
      __global const float* x = query + (long)(j * 3 + c) * 3 * n;
      __global const float* y = search_entry(lum, chroma, plane_p2[j], plane_i2[j], c, n);
      // Entry blocks hold all their channels' values, then all means, then all variances.
      const int ystride = c == 0 ? n : 2 * n;
      const int scaled = search_scales(hdr, c);
      const float b = scaled ? s * plane_f[j] : 1.0f;
      const float a = scaled ? search_offset(hdr, c) * (1.0f - b) : 0.0f;
      const float c1 = consts[c], c2 = consts[3 + c];
      for (int r = 0; r < rows; ++r) {
        const int r0 = r - radius < 0 ? 0 : r - radius, r1 = r + radius > rows - 1 ? rows - 1 : r + radius;
        for (int col = 0; col < cols; ++col) {
          const int k0 = col - radius < 0 ? 0 : col - radius, k1 = col + radius > cols - 1 ? cols - 1 : col + radius;
          float exy = 0.0f;
          for (int rr = r0; rr <= r1; ++rr)
            for (int k = k0; k <= k1; ++k) exy += x[rr * cols + k] * y[rr * cols + k];
          const int i = r * cols + col;
          const float xm = x[n + i], ym = y[ystride + i];
          const float mx = xm, my = a + b * ym;
          const float cov = b * (exy * inv_count[i] - xm * ym);
          const float vx = x[2 * n + i], vy = b * b * y[2 * ystride + i];
          const float v = ((2.0f * mx * my + c1) * (2.0f * cov + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2));
          int bin = (int)(v * (float)SEARCH_BINS);
          bin = bin < 0 ? 0 : (bin > SEARCH_BINS - 1 ? SEARCH_BINS - 1 : bin);
          histogram[bin] += 1u;
        }
      }
    }
  }
  unsigned seen = 0;
  for (int bin = 0; bin < SEARCH_BINS; ++bin) {
    seen += histogram[bin];
    if (seen >= (unsigned)keep) return bin;
  }
  return SEARCH_BINS - 1;
}

#ifndef SEARCH_REFERENCE
// One work-item per (texel t, candidate slot k) of `texels` texels with `slots` candidates each.
__kernel void search_bins(__global const float* queries, __global const float* consts,
                          __global const unsigned* candidates, int texels, int slots, __global const unsigned* plane_p2,
                          __global const unsigned* plane_i2, __global const float* plane_f, int planes,
                          __global const float* lum, __global const float* chroma, __global const float* inv_count,
                          int rows, int cols, int radius, int hdr, int keep, __global int* bins) {
  const int id = (int)get_global_id(0);
  if (id >= texels * slots) return;
  const int t = id / slots;
  const long e = (long)candidates[id] * planes;
  const long query_stride = (long)planes * 3 * 3 * rows * cols;
  bins[id] = search_bin_item(queries + t * query_stride, consts + t * 6, plane_p2 + e, plane_i2 + e, plane_f + e, lum,
                             chroma, inv_count, rows, cols, radius, planes, hdr, keep);
}
#endif
