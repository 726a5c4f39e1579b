// Batched phase-3 search (pipeline/encode/frozen_search.h, docs/similarity.md "Batched search").
//
// One work-item searches one texel: it scores its candidate P4 entries in the given (proxy) order,
// each with its least-squares RGB scale, and abandons a candidate as soon as more than the outlier
// fraction of its SSIM values fall below the best score so far (paper Sec. 4.4): most candidates
// stop after a few planes. A candidate that completes gets the histogram bin (SEARCH_BINS bins over
// [0, 1]) of its (keep)-th smallest value, a bracket around its SSIM-percentile score; the host
// settles the few completed candidates whose brackets reach the best one exactly
// (Encoder::encode_frozen_among), so the chosen entry is exactly the pruned search's.
//
// PoCL does not vectorize loops of this size across work-items, so the vectors are explicit: a plane
// of rows x cols samples (11 x 11 by default) is held as rows of 16 float lanes, padded with a zero
// border of `radius` rows and columns. The truncated box filter of the window cross term is then
// shifted adds of whole rows (zeros add nothing) and every SSIM value of a row is one float16
// expression. The C++ reference is search_reference() in pipeline/encode/frozen_search.cpp.
//
// Layouts (padded block of one plane channel: values (rows + 2 radius) x 16, window means rows x 16,
// window variances rows x 16; sample (r, c) at padded row r + radius, lane c + radius):
//   queries  per texel: [plane][channel 0..2] blocks
//   consts   per texel: c1[3], c2[3]
//   lum      per P2 entry: one block;  chroma per I2 entry: blocks a, b
//   plane_*  per P4 entry: its planes' P2 entry, I2 entry and scale factor (P4 x P3 scale)
//   nums     per (texel, slot): the candidate's least-squares numerator, sum of f (x - offset)(y - offset)
//   entry_yy per P4 entry: its least-squares denominator, sum of f^2 (y - offset)^2 over scaled channels
//   scratch  per texel: planes x 3 x rows x 2 x 16 floats, the current candidate's SSIM numerators
//            and denominators by rows
// Query and code-book values and window means are stored minus the channel offset (16 / 128 for LDR
// luminance / chroma, 0 for HDR); window variances as they are.
//   bins     per (texel, slot): the completed candidate's bin, or -1 if it was abandoned

#define SEARCH_BINS 512
#define SEARCH_MAX_ROWS 30
#define SEARCH_MAX_PLANES 256
// Lanes that hold no sample get this numerator (and denominator 1): above every SSIM value and every
// bin edge, never counted.
#define SEARCH_IDLE 4.0f

float search_offset(int hdr, int c) { return hdr ? 0.0f : (c == 0 ? 16.0f : 128.0f); }
int search_scales(int hdr, int c) { return !hdr || c == 0; }

// Lane i of the result is lane i - 1 (or i + 1) of v; zeros enter at the edge.
float16 lanes_right1(float16 v) { return (float16)(0.0f, v.s0123, v.s4567, v.s89ab, v.scde); }
float16 lanes_left1(float16 v) { return (float16)(v.s1234, v.s5678, v.s9abc, v.sdef, 0.0f); }
float16 lanes_right2(float16 v) { return (float16)(0.0f, 0.0f, v.s0123, v.s4567, v.s89ab, v.scd); }
float16 lanes_left2(float16 v) { return (float16)(v.s2345, v.s6789, v.sabcd, v.sef, 0.0f, 0.0f); }

float16 window_row(float16 p, int radius) {
  float16 h = p;
  if (radius >= 1) h += lanes_right1(p) + lanes_left1(p);
  if (radius >= 2) h += lanes_right2(p) + lanes_left2(p);
  return h;
}

int count_sum(int16 v) {
  int8 a = v.lo + v.hi;
  int4 b = a.lo + a.hi;
  int2 c = b.lo + b.hi;
  return c.x + c.y;
}

// Blocks are addressed in whole rows of 16 lanes: PoCL splits vload16 into pairs of floats, while
// float16 pointers load whole aligned rows (every block starts on a row, buffers are aligned).
__global const float16* search_block(__global const float16* lum, __global const float16* chroma, unsigned p2,
                                     unsigned i2, int c, int block) {
  return c == 0 ? lum + (long)p2 * block : chroma + ((long)i2 * 2 + (c - 1)) * block;
}

// How many SSIM values fall into bins 0..bin of the histogram (SEARCH_BINS bins over [0, 1], values
// below 0 in bin 0, above 1 in the last): a value's bin is (int)(v * SEARCH_BINS), clamped, so it is
// at most `bin` exactly when v * SEARCH_BINS < bin + 1, i.e. num * SEARCH_BINS < (bin + 1) den (den > 0).
int search_count_upto(__global const float16* terms, int rows16, int bin) {
  const float edge = (float)(bin + 1);
  int16 count = 0;
  for (int i = 0; i < rows16; ++i) count -= isless(terms[2 * i] * (float)SEARCH_BINS, terms[2 * i + 1] * edge);
  return count_sum(count);
}

// Bin of the (keep)-th smallest value of a completed candidate, by bisection over the bins with
// vectorized counting passes (a scalar histogram costs as much as scoring a candidate).
int search_percentile_bin(__global const float16* terms, int rows16, int keep) {
  int lo = 0, hi = SEARCH_BINS - 1;
  while (lo < hi) {
    const int mid = (lo + hi) / 2;
    if (search_count_upto(terms, rows16, mid) >= keep) hi = mid;
    else lo = mid + 1;
  }
  return lo;
}

// Sorts the planes by how many of the completed candidate's values fall into bins 0..bin, most
// first (stable: equal counts keep plane order).
void search_order_planes(__global const float16* terms, int planes, int rows, int bin, uchar* order) {
  int low[SEARCH_MAX_PLANES];
  for (int j = 0; j < planes; ++j) low[j] = search_count_upto(terms + j * 3 * rows * 2, 3 * rows, bin);
  for (int i = 1; i < planes; ++i) {
    const uchar j = order[i];
    int at = i;
    while (at > 0 && low[order[at - 1]] < low[j]) {
      order[at] = order[at - 1];
      --at;
    }
    order[at] = j;
  }
}

__kernel void search_texels(__global const float16* queries, __global const float* consts,
                            __global const unsigned* candidates, __global const float* nums, int texels, int slots,
                            __global const unsigned* plane_p2, __global const unsigned* plane_i2,
                            __global const float* plane_f, __global const float* entry_yy, int planes,
                            __global const float16* lum, __global const float16* chroma,
                            __global const float16* inv_count, int rows, int cols, int radius, int hdr, int keep,
                            __global float16* scratch,
                            __global int* bins) {
  const int t = (int)get_global_id(0);
  if (t >= texels) return;
  const int padded = rows + 2 * radius, block = padded + 2 * rows;  // rows of 16 lanes
  __global const float16* query = queries + (long)t * planes * 3 * block;
  __global float16* terms = scratch + (long)t * planes * 3 * rows * 2;
  const float16 lane = (float16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const int16 used = isgreaterequal(lane, (float16)(float)radius) & isless(lane, (float16)(float)(radius + cols));
  // Best score so far, lowered by the bracket margin (pipeline/encode/frozen_search.cpp kMargin).
  float floor = -1e30f;
  // Planes in the order they are scored: once the first candidate completes, the planes that hold
  // most of its lowest values come first, since that is where the other candidates fail too, and a
  // candidate is abandoned once enough of its values are low (the set of values is the same).
  uchar order[SEARCH_MAX_PLANES];
  for (int j = 0; j < planes; ++j) order[j] = (uchar)j;
  for (int k = 0; k < slots; ++k) {
    const unsigned entry = candidates[(long)t * slots + k];
    const long e = (long)entry * planes;
    __global const unsigned* p2 = plane_p2 + e;
    __global const unsigned* i2 = plane_i2 + e;
    __global const float* f = plane_f + e;
    // The least-squares scale over the channels it acts on: the host computes its numerator
    // (FrozenSearch::scale_numerators, all planes of every candidate, with the batch's shared
    // code-book planes in cache) and each entry's denominator.
    const float num = nums[(long)t * slots + k], den = entry_yy[entry];
    const float s = den > 1e-20f ? (num / den > 0.0f ? num / den : 0.0f) : 1.0f;

    // Each SSIM value is kept as numerator and denominator: v < floor is num < floor * den (den > 0),
    // no division in the loop.
    int below = 0;
    for (int q = 0; q < planes && below < keep; ++q) {
      const int j = order[q];
      int16 count = 0;
      for (int c = 0; c < 3; ++c) {
        __global const float16* x = query + (j * 3 + c) * block;
        __global const float16* y = search_block(lum, chroma, p2[j], i2[j], c, block);
        __global const float16* xm = x + padded;
        __global const float16* ym = y + padded;
        __global float16* out = terms + (j * 3 + c) * rows * 2;
        const float b = search_scales(hdr, c) ? s * f[j] : 1.0f, o = search_offset(hdr, c);
        const float c1 = consts[t * 6 + c], c2 = consts[t * 6 + 3 + c];
        float16 h[SEARCH_MAX_ROWS + 4];
        for (int r = 0; r < padded; ++r)
          h[r] = r < radius || r >= radius + rows ? (float16)0.0f : window_row(x[r] * y[r], radius);
        for (int r = 0; r < rows; ++r) {
          float16 exy = h[r];
          for (int d = 1; d <= 2 * radius; ++d) exy += h[r + d];
          // Offset-removed means: the covariance is the same, the absolute means add the offset back
          // (a scaled channel maps y to o + b (y - o)).
          const float16 xc = xm[r], yc = ym[r];
          const float16 mx = o + xc, my = o + b * yc;
          const float16 cov = b * (exy * inv_count[r] - xc * yc);
          const float16 vx = xm[r + rows], vy = b * b * ym[r + rows];
          const float16 num_v = select((float16)SEARCH_IDLE, (2.0f * mx * my + c1) * (2.0f * cov + c2), used);
          const float16 den_v = select((float16)1.0f, (mx * mx + my * my + c1) * (vx + vy + c2), used);
          count -= isless(num_v, floor * den_v);
          out[2 * r] = num_v;
          out[2 * r + 1] = den_v;
        }
      }
      below += count_sum(count);
    }
    if (below >= keep) {
      bins[(long)t * slots + k] = -1;
      continue;
    }
    const int bin = search_percentile_bin(terms, planes * 3 * rows, keep);
    bins[(long)t * slots + k] = bin;
    if (k == 0) search_order_planes(terms, planes, rows, bin, order);
    const float lower = bin <= 0 ? -1e30f : (float)bin / (float)SEARCH_BINS - 5e-4f;
    floor = lower > floor ? lower : floor;
  }
}
