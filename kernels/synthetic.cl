// Rendering of a synthetic BTF from a height-field material (pipeline/io/synthetic.h).
//
// This file is both the OpenCL program and, included by pipeline/io/synthetic.cpp with a small prelude,
// the C++ reference: one text, so the two paths cannot drift apart. It therefore sticks to the C
// subset both languages share (scalar floats, a struct, no vector types, no OpenCL-only built-ins);
// only the __kernel entry points at the end are OpenCL-only.
//
// Geometry: texel (x, y) of the rectified image shows the ray that leaves the reference plane point
// (x, y, 0) towards the viewer. Heights are in texel units. Maps wrap (the material is tileable).
//
// Per-texel material record, SYNTH_STRIDE floats:
//   0 height, 1..3 shading normal, 4..6 diffuse albedo (linear RGB), 7..9 specular F0 (RGB),
//   10 GGX alpha along the tangent, 11 alpha across it, 12..13 tangent (cos, sin) in the plane.

#define SYNTH_STRIDE 16
#define SYNTH_PI 3.14159265f
// Fixed ray-march step counts: the view ray finds the visible point (parallax, masking by the height
// field); the light ray finds self-shadowing. Modest counts keep a 256^2 render well under a minute.
#define SYNTH_VIEW_STEPS 20
#define SYNTH_LIGHT_STEPS 12
// An occluder this many texel-heights above the light ray gives full shadow; less gives a soft
// penumbra, which also keeps the OpenCL and C++ paths from flipping hard decisions on rounding.
#define SYNTH_SHADOW_SHARPNESS 3.0f
// Light scattered in from the surroundings, so that shadowed texels are dark but not black.
#define SYNTH_AMBIENT 0.03f
// Entries of the linear -> 8-bit sRGB table (fine enough that the quantisation is < 0.1 code).
#define SYNTH_SRGB_LUT 65536

typedef struct {
  float x, y, z;
} SynthVec;

SynthVec synth_vec(float x, float y, float z) {
  SynthVec v;
  v.x = x;
  v.y = y;
  v.z = z;
  return v;
}

float synth_dot(SynthVec a, SynthVec b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

SynthVec synth_normalize(SynthVec a) {
  const float inv = 1.0f / sqrt(fmax(synth_dot(a, a), 1e-20f));
  return synth_vec(a.x * inv, a.y * inv, a.z * inv);
}

SynthVec synth_cross(SynthVec a, SynthVec b) {
  return synth_vec(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}

int synth_wrap(int i, int n) {
  const int r = i % n;
  return r < 0 ? r + n : r;
}

// Bilinear lookup of one channel of a wrapped map with `stride` floats per texel.
float synth_sample(__global const float* map, int stride, int channel, int width, int height, float x, float y) {
  const float fx = floor(x), fy = floor(y);
  const float ax = x - fx, ay = y - fy;
  const int x0 = synth_wrap((int)fx, width), y0 = synth_wrap((int)fy, height);
  const int x1 = synth_wrap(x0 + 1, width), y1 = synth_wrap(y0 + 1, height);
  const float v00 = map[(y0 * width + x0) * stride + channel], v10 = map[(y0 * width + x1) * stride + channel];
  const float v01 = map[(y1 * width + x0) * stride + channel], v11 = map[(y1 * width + x1) * stride + channel];
  const float top = v00 + (v10 - v00) * ax, bottom = v01 + (v11 - v01) * ax;
  return top + (bottom - top) * ay;
}

float synth_height(__global const float* maps, int width, int height, float x, float y) {
  return synth_sample(maps, SYNTH_STRIDE, 0, width, height, x, y);
}

// Self-shadowing of texel `texel` from light direction `light` (unit vector, z up): march from the
// surface towards the light until the ray is above the highest point of the field.
float synth_shadow(__global const float* maps, int width, int height, float height_max, int texel, SynthVec light) {
  if (light.z > 0.9999f) return 1.0f;
  const float x = (float)(texel % width), y = (float)(texel / width);
  const float h0 = maps[texel * SYNTH_STRIDE];
  const float dx = light.x / light.z, dy = light.y / light.z;
  const float rise = fmax(height_max - h0, 0.0f);
  float occlusion = 0.0f;
  for (int s = 1; s <= SYNTH_LIGHT_STEPS; ++s) {
    const float up = rise * (float)s / (float)SYNTH_LIGHT_STEPS;
    const float surface = synth_height(maps, width, height, x + dx * up, y + dy * up);
    occlusion = fmax(occlusion, surface - (h0 + up));
  }
  return clamp(1.0f - occlusion * SYNTH_SHADOW_SHARPNESS, 0.0f, 1.0f);
}

// The reference-plane position of the visible surface point along the view ray of texel (x, y):
// march down from the top of the field, refine linearly between the last two steps.
void synth_visible_point(__global const float* maps, int width, int height, float height_max, float x, float y,
                         SynthVec view, float* hit_x, float* hit_y) {
  *hit_x = x;
  *hit_y = y;
  if (view.z > 0.9999f) return;
  const float dx = view.x / view.z, dy = view.y / view.z;
  float prev_h = height_max;
  float prev_gap = height_max - synth_height(maps, width, height, x + dx * prev_h, y + dy * prev_h);
  if (prev_gap <= 0.0f) {
    *hit_x = x + dx * prev_h;
    *hit_y = y + dy * prev_h;
    return;
  }
  for (int s = 1; s <= SYNTH_VIEW_STEPS; ++s) {
    const float h = height_max * (1.0f - (float)s / (float)SYNTH_VIEW_STEPS);
    const float gap = h - synth_height(maps, width, height, x + dx * h, y + dy * h);
    if (gap <= 0.0f) {
      const float t = prev_gap / (prev_gap - gap);
      const float hit_h = prev_h + (h - prev_h) * t;
      *hit_x = x + dx * hit_h;
      *hit_y = y + dy * hit_h;
      return;
    }
    prev_h = h;
    prev_gap = gap;
  }
}

// Smith's Lambda for anisotropic GGX, direction in the (tangent, bitangent, normal) frame.
float synth_ggx_lambda(float wt, float wb, float wn, float alpha_t, float alpha_b) {
  const float n2 = fmax(wn * wn, 1e-8f);
  const float a2 = (alpha_t * alpha_t * wt * wt + alpha_b * alpha_b * wb * wb) / n2;
  return 0.5f * (sqrt(1.0f + a2) - 1.0f);
}

// The visible surface point of one (texel, view): its shading frame and material, and everything
// about the view direction that does not change with the light.
typedef struct {
  SynthVec normal, tangent, bitangent, view;
  float albedo[3];
  float f0[3];
  float alpha_t, alpha_b;
  float n_v, lambda_v;
} SynthPoint;

SynthPoint synth_point_at(__global const float* maps, int width, int height, float x, float y, SynthVec view) {
  float r[SYNTH_STRIDE];
  for (int c = 0; c < 14; ++c) r[c] = synth_sample(maps, SYNTH_STRIDE, c, width, height, x, y);
  SynthPoint s;
  s.normal = synth_normalize(synth_vec(r[1], r[2], r[3]));
  // Gram-Schmidt: the tangent direction projected onto the shading plane.
  const SynthVec t0 = synth_vec(r[12], r[13], 0.0f);
  const float along = synth_dot(t0, s.normal);
  s.tangent = synth_normalize(synth_vec(t0.x - s.normal.x * along, t0.y - s.normal.y * along, -s.normal.z * along));
  s.bitangent = synth_cross(s.normal, s.tangent);
  for (int c = 0; c < 3; ++c) {
    s.albedo[c] = r[4 + c];
    s.f0[c] = r[7 + c];
  }
  s.alpha_t = fmax(r[10], 0.02f);
  s.alpha_b = fmax(r[11], 0.02f);
  s.view = view;
  s.n_v = fmax(synth_dot(s.normal, view), 1e-4f);
  s.lambda_v = synth_ggx_lambda(synth_dot(view, s.tangent), synth_dot(view, s.bitangent), s.n_v, s.alpha_t, s.alpha_b);
  return s;
}

// Reflected radiance of the point for unit irradiance from `light`: (Lambert + anisotropic GGX with
// height-correlated Smith masking and Schlick Fresnel) times the cosine of incidence on the local
// surface times shadowing, plus a small ambient term. Written without data-dependent branches so the
// OpenCL compiler can vectorise it. Writes linear RGB to out.
void synth_radiance(const SynthPoint* s, SynthVec light, float shadow, float* out) {
  const float n_l = synth_dot(s->normal, light);
  const float lit = (n_l > 0.0f && light.z > 0.0f) ? shadow : 0.0f;
  const float n_l_c = fmax(n_l, 1e-4f);
  const SynthVec h = synth_normalize(synth_vec(light.x + s->view.x, light.y + s->view.y, light.z + s->view.z));
  const float ht = synth_dot(h, s->tangent) / s->alpha_t, hb = synth_dot(h, s->bitangent) / s->alpha_b;
  const float hn = fmax(synth_dot(h, s->normal), 0.0f);
  const float q = ht * ht + hb * hb + hn * hn;
  const float d = hn / fmax(hn, 1e-6f) / (SYNTH_PI * s->alpha_t * s->alpha_b * q * q);
  const float lambda_l =
      synth_ggx_lambda(synth_dot(light, s->tangent), synth_dot(light, s->bitangent), n_l_c, s->alpha_t, s->alpha_b);
  const float g = 1.0f / (1.0f + s->lambda_v + lambda_l);
  const float m = 1.0f - clamp(synth_dot(s->view, h), 0.0f, 1.0f);
  const float m5 = m * m * m * m * m;
  // D G F / (4 n.l n.v) times n.l: the n.l cancels.
  const float specular = lit * d * g / (4.0f * s->n_v);
  const float diffuse = lit * n_l_c / SYNTH_PI + SYNTH_AMBIENT;
  for (int c = 0; c < 3; ++c) out[c] = s->albedo[c] * diffuse + specular * (s->f0[c] + (1.0f - s->f0[c]) * m5);
}

// 8-bit sRGB code of a linear value through the table (both paths share the table, so they agree).
uchar synth_encode(__global const uchar* srgb_lut, float linear) {
  const float v = clamp(linear, 0.0f, 1.0f) * (float)(SYNTH_SRGB_LUT - 1) + 0.5f;
  return srgb_lut[(int)v];
}

// One work item of the shading pass: texel `texel`, view `view`, all lights. Output is texel-major
// relative to `first_texel`: ((texel - first_texel) * views * lights + view * lights + light) * 3.
void synth_shade_item(__global const float* maps, __global const float* shadows, __global const float* views,
                      __global const float* lights, __global const uchar* srgb_lut, int width, int height,
                      float height_max, float exposure, int view_count, int light_count, int first_texel, int texel,
                      int view, int hdr, __global uchar* out_ldr, __global float* out_hdr) {
  const SynthVec v = synth_vec(views[3 * view], views[3 * view + 1], views[3 * view + 2]);
  float hx, hy;
  synth_visible_point(maps, width, height, height_max, (float)(texel % width), (float)(texel / width), v, &hx, &hy);
  const SynthPoint s = synth_point_at(maps, width, height, hx, hy, v);
  // The shadow maps of all lights are interpolated at the same point: one set of weights.
  const float fx = floor(hx), fy = floor(hy);
  const float ax = hx - fx, ay = hy - fy;
  const int x0 = synth_wrap((int)fx, width), y0 = synth_wrap((int)fy, height);
  const int x1 = synth_wrap(x0 + 1, width), y1 = synth_wrap(y0 + 1, height);
  const int i00 = y0 * width + x0, i10 = y0 * width + x1, i01 = y1 * width + x0, i11 = y1 * width + x1;
  const int texels = width * height;
  const long base = ((long)(texel - first_texel) * view_count * light_count + (long)view * light_count) * 3;
  for (int l = 0; l < light_count; ++l) {
    const SynthVec L = synth_vec(lights[3 * l], lights[3 * l + 1], lights[3 * l + 2]);
    __global const float* layer = shadows + (long)l * texels;
    const float top = layer[i00] + (layer[i10] - layer[i00]) * ax;
    const float bottom = layer[i01] + (layer[i11] - layer[i01]) * ax;
    float rgb[3];
    synth_radiance(&s, L, top + (bottom - top) * ay, rgb);
    if (hdr) {
      for (int c = 0; c < 3; ++c) out_hdr[base + 3 * l + c] = rgb[c] * exposure;
    } else {
      for (int c = 0; c < 3; ++c) out_ldr[base + 3 * l + c] = synth_encode(srgb_lut, rgb[c] * exposure);
    }
  }
}

#ifndef SYNTH_REFERENCE
// Shadow map: shadows[light * texels + texel].
__kernel void synth_shadow_map(__global const float* maps, __global const float* lights, int width, int height,
                               float height_max, int light_count, __global float* shadows) {
  const int i = (int)get_global_id(0);
  const int texels = width * height;
  if (i >= texels * light_count) return;
  const int l = i / texels, texel = i % texels;
  const SynthVec L = synth_vec(lights[3 * l], lights[3 * l + 1], lights[3 * l + 2]);
  shadows[i] = synth_shadow(maps, width, height, height_max, texel, L);
}

// One work item per (texel, view) of texels first_texel .. first_texel + texel_count - 1.
__kernel void synth_shade(__global const float* maps, __global const float* shadows, __global const float* views,
                          __global const float* lights, __global const uchar* srgb_lut, int width, int height,
                          float height_max, float exposure, int view_count, int light_count, int first_texel,
                          int texel_count, int hdr, __global uchar* out_ldr, __global float* out_hdr) {
  const int i = (int)get_global_id(0);
  if (i >= texel_count * view_count) return;
  synth_shade_item(maps, shadows, views, lights, srgb_lut, width, height, height_max, exposure, view_count,
                   light_count, first_texel, first_texel + i / view_count, i % view_count, hdr, out_ldr, out_hdr);
}
#endif
