#include "pipeline/decode/decoder.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include <btfvq/error.h>
#include "pipeline/runtime/opencl_runtime.h"
#include "pipeline/parametrization.h"
#include "pipeline/util/parallel.h"

namespace btfvq {

namespace {

// The cubic Hermite of docs/btfbase-format.md step 4 inside beta cell i at parameter t. The weights depend only
// on the query, so they are computed once and applied to every P1 row the query touches.
struct Hermite {
  int i = 0;
  bool first = false, last = false;
  double h00 = 0, h10 = 0, h01 = 0, h11 = 0;

  Hermite(int cell, double t, int n_beta) : i(cell), first(cell == 0), last(cell == n_beta - 2) {
    h01 = -2 * t * t * t + 3 * t * t;
    h00 = 1 - h01;
    h11 = t * t * t - t * t;
    h10 = h11 - t * t + t;
  }
  double operator()(const float* s) const {
    const double p0 = s[i], p1 = s[i + 1];
    const double m0 = first ? p1 - p0 : (p1 - double(s[i - 1])) / 2;
    const double m1 = last ? p1 - p0 : (double(s[i + 1]) - p0) / 2;  // (sic): the original's tangent
    return h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1;
  }
};

int wrap(int v, int n) {
  const int r = v % n;
  return r < 0 ? r + n : r;
}

}  // namespace

struct Decoder::DeviceBuffers {
  cl::Context context;  // the buffers belong to it; a reconfigured device has a new one
  cl::Buffer p1, c, i1, i2, m, beta_nodes;
  cl::Buffer p2, p3, p4, p6;  // (index, scale) pairs: one look-up, one cache line
  std::vector<int32_t> p6_offset;  // per material: where its P6 starts in the concatenated P6
  // The kernel with the code-books bound, and the query and result buffers of one chunk, reused
  // from call to call (guarded by Decoder::device_mutex_ for the length of a batch).
  cl::Kernel kernel;
  size_t capacity = 0;
  cl::Buffer texels, theta_i, phi_i, theta_v, phi_v, rgb;
};

Decoder::Decoder(const Database& db) : db_(db) {
  db.codebooks.grid.validate();
  db.validate();
  const Codebooks& k = db.codebooks;
  nb_ = k.grid.n_beta;
  na_ = k.grid.n_alpha;
  nt_ = size_t(k.grid.n_theta_v);
  np_ = size_t(k.grid.n_phi_v);
  for (int i = 0; i < nb_; ++i) beta_nodes_.push_back(k.grid.beta_node(i));
  p1_ = k.p1.data().data();
  c_ = k.c.data().data();
  i1_ = k.i1.data().data();
  i2_ = k.i2.data().data();
  p2_index_ = k.p2_index.data().data();
  p2_scale_ = k.p2_scale.data().data();
  m_ = k.m.data().data();
  p3_index_ = k.p3_index.data().data();
  p3_scale_ = k.p3_scale.data().data();
  p4_index_ = k.p4_index.data().data();
  p4_scale_ = k.p4_scale.data().data();
}

Decoder::~Decoder() = default;

void Decoder::check_material(size_t material) const {
  if (material >= db_.materials.size())
    throw NotFoundError("material index " + std::to_string(material) + " is past the end of the database (" +
                        std::to_string(db_.materials.size()) + " materials)");
}

Rgb Decoder::evaluate(size_t material, int x, int y, const Direction& light, const Direction& view) const {
  check_material(material);
  // Zero below the horizon; written so that NaN angles also decode to zero.
  if (!(light.theta <= 90.0 && view.theta <= 90.0) || !std::isfinite(light.phi) || !std::isfinite(view.phi)) return {};
  const Material& mat = db_.materials[material];
  if (mat.width <= 0 || mat.height <= 0) return {};
  const size_t texel = size_t(wrap(y, mat.height)) * size_t(mat.width) + size_t(wrap(x, mat.width));
  const int32_t p4_row = mat.p6_index[texel];
  if (p4_row < 0) return {};
  const Rgb v = evaluate_p4(uint32_t(p4_row), mat.dynamic == Dynamic::HDR, light, view);
  const double s6 = double(mat.p6_scale[texel]);
  return {float(v.r * s6), float(v.g * s6), float(v.b * s6)};
}

namespace {

// Everything docs/btfbase-format.md steps 1-4 and 6 derive from the directions alone: the interpolation cells and
// weights. A renderer asks for many texels under one light and view, so the last geometry each
// thread computed is kept and reused when the directions and the grid are the same (the values are
// those the computation gives, so results do not depend on the cache).
struct Geometry {
  double light_theta = std::nan(""), light_phi = 0, view_theta = 0, view_phi = 0;
  int nb = 0, na = 0, nt = 0, np = 0;
  Hermite hermite{0, 0.0, 3};
  double bw = 0;
  int alpha_node[2] = {0, 0};
  double alpha_w[2] = {0, 0};
  int phi_node[2] = {0, 0};
  double phi_w[2] = {0, 0};
  int theta_node[2] = {0, 0};
  double theta_w[2] = {0, 0};

  bool same(const Direction& light, const Direction& view, const AngularGrid& g) const {
    return light.theta == light_theta && light.phi == light_phi && view.theta == view_theta && view.phi == view_phi &&
           g.n_beta == nb && g.n_alpha == na && g.n_theta_v == nt && g.n_phi_v == np;
  }
};

void compute_geometry(Geometry& geo, const AngularGrid& grid, const std::vector<double>& beta_nodes,
                      const Direction& light, const Direction& view) {
  const int nb = grid.n_beta;
  // Steps 1-3: onion angles of the light for this view azimuth (to_onion of parametrization.h, with
  // sin(beta) = x and cos(beta) = sqrt(1 - x^2) instead of two more trigonometric calls), and the
  // four interpolation cells.
  const double phi = relative_light_azimuth(light.phi, view.phi) * kDeg, sin_t = std::sin(light.theta * kDeg);
  const double sb = std::clamp(std::cos(phi) * sin_t, -1.0, 1.0), ly = std::sin(phi) * sin_t;
  const double cos_b = std::sqrt(1.0 - sb * sb);
  const OnionAngles onion{cos_b > 0 ? std::asin(std::clamp(ly / cos_b, -1.0, 1.0)) / kDeg : 0.0, std::asin(sb) / kDeg};
  const int bi = std::clamp(int(std::floor((sb + 1.0) / 2.0 * (nb - 1))), 0, nb - 2);
  geo.bw = std::clamp((onion.beta - beta_nodes[size_t(bi)]) / (beta_nodes[size_t(bi) + 1] - beta_nodes[size_t(bi)]), 0.0, 1.0);
  geo.hermite = Hermite(bi, geo.bw, nb);
  const Cell ac = grid.alpha_cell(onion.alpha);
  const Cell tc = grid.theta_v_cell(view.theta);
  const Cell pc = grid.phi_v_cell(view.phi);
  geo.alpha_node[0] = ac.i0;
  geo.alpha_node[1] = ac.i1;
  geo.alpha_w[0] = 1.0 - ac.w;
  geo.alpha_w[1] = ac.w;
  geo.phi_node[0] = pc.i0;
  geo.phi_node[1] = pc.i1;
  geo.phi_w[0] = 1.0 - pc.w;
  geo.phi_w[1] = pc.w;
  geo.theta_node[0] = tc.i0;
  geo.theta_node[1] = tc.i1;
  geo.theta_w[0] = tc.i0 == tc.i1 ? 1.0 : 1.0 - tc.w;
  geo.theta_w[1] = tc.i0 == tc.i1 ? 0.0 : tc.w;
  geo.light_theta = light.theta;
  geo.light_phi = light.phi;
  geo.view_theta = view.theta;
  geo.view_phi = view.phi;
  geo.nb = grid.n_beta;
  geo.na = grid.n_alpha;
  geo.nt = grid.n_theta_v;
  geo.np = grid.n_phi_v;
}

}  // namespace

Rgb Decoder::evaluate_p4(uint32_t p4_row, bool hdr, const Direction& light, const Direction& view) const {
  if (!(light.theta <= 90.0 && view.theta <= 90.0) || !std::isfinite(light.phi) || !std::isfinite(view.phi)) return {};
  thread_local Geometry geo;
  if (!geo.same(light, view, db_.codebooks.grid)) compute_geometry(geo, db_.codebooks.grid, beta_nodes_, light, view);
  const Hermite& hermite = geo.hermite;
  const double bw = geo.bw;
  const size_t beta0 = size_t(hermite.i), beta1 = beta0 + 1;

  // The code-books are followed level by level for all (up to) four M entries and both alpha nodes
  // at once, so that the look-ups of one level do not wait for each other (for random queries the
  // tables are not in cache and each level is a memory latency). The arithmetic below is the same
  // as entry by entry.
  // Step 6 nodes: P4 over phi_v (wrapping), P3 over theta_v.
  const size_t p4 = size_t(p4_row) * np_;
  size_t p3_row[2];
  for (int p = 0; p < 2; ++p) p3_row[p] = size_t(p4_index_[p4 + size_t(geo.phi_node[p])]) * nt_;
  uint32_t mi[2][2];
  for (int p = 0; p < 2; ++p)
    for (int t = 0; t < 2; ++t) mi[p][t] = p3_index_[p3_row[p] + size_t(geo.theta_node[t])];
  // Step 5 rows: M -> (P2 row, I2 row) -> per alpha node (P1 row, P2 scale) and I1 row.
  const float* p1_row[2][2][2];
  float p2s[2][2][2];
  const uint32_t* i1_row[2][2][2];
  for (int p = 0; p < 2; ++p)
    for (int t = 0; t < 2; ++t) {
      const uint32_t* me = m_ + size_t(mi[p][t]) * 2;
      const size_t p2 = size_t(me[0]) * size_t(na_), i2 = size_t(me[1]) * size_t(na_);
      for (int a = 0; a < 2; ++a) {
        const size_t an = size_t(geo.alpha_node[a]);
        p1_row[p][t][a] = p1_ + size_t(p2_index_[p2 + an]) * size_t(nb_);
        p2s[p][t][a] = p2_scale_[p2 + an];
        i1_row[p][t][a] = i1_ + size_t(i2_[i2 + an]) * size_t(nb_);
      }
    }

  // Step 5: one M entry -> RGB.
  auto decode_m = [&](int p, int t) {
    double yy = 0, cb = 0, cr = 0;
    for (int a = 0; a < 2; ++a) {
      const double w = geo.alpha_w[a];
      yy += w * double(p2s[p][t][a]) * hermite(p1_row[p][t][a]);
      const float* c0 = c_ + size_t(i1_row[p][t][a][beta0]) * 2;
      const float* c1 = c_ + size_t(i1_row[p][t][a][beta1]) * 2;
      cb += w * ((1.0 - bw) * double(c0[0]) + bw * double(c1[0]));
      cr += w * ((1.0 - bw) * double(c0[1]) + bw * double(c1[1]));
    }
    return from_coding_space({float(yy), float(cb), float(cr)}, hdr);
  };

  // Step 6: P4 over phi_v (wrapping), P3 over theta_v, each node with its own scale; then P6.
  double r = 0, g = 0, b = 0;
  for (int p = 0; p < 2; ++p) {
    if (geo.phi_w[p] == 0.0) continue;
    const double s4 = geo.phi_w[p] * double(p4_scale_[p4 + size_t(geo.phi_node[p])]);
    for (int t = 0; t < 2; ++t) {
      if (geo.theta_w[t] == 0.0) continue;
      const double s = s4 * geo.theta_w[t] * double(p3_scale_[p3_row[p] + size_t(geo.theta_node[t])]);
      const Rgb v = decode_m(p, t);
      r += s * double(v.r);
      g += s * double(v.g);
      b += s * double(v.b);
    }
  }
  return {float(r), float(g), float(b)};
}

std::vector<Rgb> Decoder::decode(const std::vector<DecodeQuery>& queries) const {
  return ComputeDevice::get().backend() == Backend::OpenCL ? decode_opencl(queries) : decode_reference(queries);
}

std::vector<Rgb> Decoder::decode_reference(const std::vector<DecodeQuery>& queries) const {
  for (const auto& q : queries) check_material(q.material);
  std::vector<Rgb> out(queries.size());
  for (size_t i = 0; i < queries.size(); ++i) {
    const DecodeQuery& q = queries[i];
    out[i] = evaluate(q.material, q.x, q.y, q.light, q.view);
  }
  return out;
}

namespace {

// OpenCL rejects zero-sized buffers; an empty code-book is uploaded as one unused element.
template <class T>
cl::Buffer upload_nonempty(ComputeDevice& dev, const std::vector<T>& v) {
  if (v.empty()) return dev.upload(std::vector<T>(1));
  return dev.upload(v);
}

// (index, scale) pairs with the scale's bits, for tables the kernel reads as both.
template <class I>
std::vector<uint32_t> interleave(const std::vector<I>& index, const std::vector<float>& scale) {
  static_assert(sizeof(I) == 4 && sizeof(float) == 4);
  std::vector<uint32_t> out(2 * index.size());
  for (size_t i = 0; i < index.size(); ++i) {
    out[2 * i] = uint32_t(index[i]);
    std::memcpy(&out[2 * i + 1], &scale[i], 4);
  }
  return out;
}

}  // namespace

Decoder::DeviceBuffers& Decoder::device_buffers() const {
  std::lock_guard<std::mutex> lock(device_mutex_);
  auto& dev = ComputeDevice::get();
  // The held buffers keep their context alive, so a new device cannot reuse its handle.
  if (device_ && device_->context() == dev.context()()) return *device_;
  const Codebooks& k = db_.codebooks;
  auto bufs = std::make_unique<DeviceBuffers>();
  opencl_call("uploading the code-books for decoding", [&] {
    bufs->context = dev.context();
    bufs->p1 = upload_nonempty(dev, k.p1.data());
    bufs->c = upload_nonempty(dev, k.c.data());
    bufs->i1 = upload_nonempty(dev, k.i1.data());
    bufs->i2 = upload_nonempty(dev, k.i2.data());
    bufs->m = upload_nonempty(dev, k.m.data());
    bufs->p2 = upload_nonempty(dev, interleave(k.p2_index.data(), k.p2_scale.data()));
    bufs->p3 = upload_nonempty(dev, interleave(k.p3_index.data(), k.p3_scale.data()));
    bufs->p4 = upload_nonempty(dev, interleave(k.p4_index.data(), k.p4_scale.data()));
    // All materials' P6 concatenated; the kernel gets texel indices into it.
    std::vector<uint32_t> p6;
    for (const auto& mat : db_.materials) {
      bufs->p6_offset.push_back(int32_t(p6.size() / 2));
      const auto pairs = interleave(mat.p6_index, mat.p6_scale);
      p6.insert(p6.end(), pairs.begin(), pairs.end());
      // A query's texel travels as 2 x index + HDR flag in an int.
      if (p6.size() / 2 >= (size_t(1) << 30)) throw DeviceError("decode_opencl: more than 2^30 texels in the database");
    }
    bufs->p6 = upload_nonempty(dev, p6);
    std::vector<float> nodes(beta_nodes_.begin(), beta_nodes_.end());
    bufs->beta_nodes = upload_nonempty(dev, nodes);
    const AngularGrid& g = k.grid;
    bufs->kernel = dev.kernel("decode.cl", "decode_batch");
    int arg = 0;
    // The pair buffers are bound twice: as the kernel's X_index and X_scale.
    for (cl::Buffer* b : {&bufs->p1, &bufs->c, &bufs->i1, &bufs->i2, &bufs->p2, &bufs->p2, &bufs->m, &bufs->p3, &bufs->p3,
                          &bufs->p4, &bufs->p4, &bufs->p6, &bufs->p6, &bufs->beta_nodes})
      bufs->kernel.setArg(arg++, *b);
    for (int v : {g.n_beta, g.n_alpha, g.n_theta_v, g.n_phi_v}) bufs->kernel.setArg(arg++, cl_int(v));
  });
  device_ = std::move(bufs);
  return *device_;
}

namespace {

// The host's part of one query: the index of its texel in the concatenated P6 of all materials
// (texel indices wrap modulo the material size), times two, plus the HDR flag; -1 for a material
// without texels.
int32_t texel_code(const Material& mat, int32_t offset, int32_t x, int32_t y) {
  if (mat.width <= 0 || mat.height <= 0) return -1;
  if (uint32_t(x) >= uint32_t(mat.width)) x = wrap(x, mat.width);
  if (uint32_t(y) >= uint32_t(mat.height)) y = wrap(y, mat.height);
  return 2 * (offset + y * mat.width + x) + (mat.dynamic == Dynamic::HDR ? 1 : 0);
}

// Runs f(begin, end) over [0, n) split across the cores: packing queries and unpacking results is
// the serial part of a batch, and while it runs the device's cores would otherwise idle. Parts are
// at least 32768 queries long, so that handing one to another thread is cheap next to running it.
template <class F>
void split_over_cores(size_t n, F&& f) {
  parallel_for(0, n, f, in_parts(n, std::min(parallel_threads(), n / 32768 + 1)));
}

}  // namespace

std::vector<Rgb> Decoder::decode_opencl(const std::vector<DecodeQuery>& queries) const {
  for (const auto& q : queries) check_material(q.material);
  std::vector<Rgb> out(queries.size());
  decode_opencl_into(queries.size(), [&](size_t i) { return queries[i]; }, out.data());
  return out;
}

void Decoder::decode(size_t n, const QuerySource& query, Rgb* out) const {
  if (ComputeDevice::get().backend() == Backend::OpenCL) {
    decode_opencl_into(n, query, out);
    return;
  }
  parallel_for(0, n, [&](size_t first, size_t last) {
    for (size_t i = first; i < last; ++i) {
      const DecodeQuery q = query(i);
      out[i] = evaluate(q.material, q.x, q.y, q.light, q.view);
    }
  });
}

void Decoder::decode_opencl_into(size_t count, const QuerySource& query, Rgb* out) const {
  auto& dev = ComputeDevice::get();
  if (!dev.uses_opencl()) throw DeviceError("decode_opencl: OpenCL is not in use (" + dev.description() + ")");
  if (count == 0) return;
  const size_t materials = db_.materials.size();
  std::lock_guard<std::mutex> lock(batch_mutex_);
  DeviceBuffers& bufs = device_buffers();
  // Chunks bound the query buffers for very large batches; each is padded to whole work-groups of
  // kQueriesPerItem-wide work-items with queries that decode to zero.
  constexpr size_t kChunk = size_t(1) << 20, kPad = 1024, kQueriesPerItem = 16;  // 16: DECODE_WIDTH of decode.cl
  const size_t capacity = std::min(kChunk, round_up(count, kPad));
  opencl_call("decode kernel", [&] {
    cl::CommandQueue& queue = dev.queue();
    if (bufs.capacity < capacity) {
      const cl_mem_flags in = CL_MEM_READ_ONLY | CL_MEM_ALLOC_HOST_PTR;
      bufs.texels = dev.allocate(capacity * sizeof(cl_int), in);
      bufs.theta_i = dev.allocate(capacity * sizeof(cl_float), in);
      bufs.phi_i = dev.allocate(capacity * sizeof(cl_float), in);
      bufs.theta_v = dev.allocate(capacity * sizeof(cl_float), in);
      bufs.phi_v = dev.allocate(capacity * sizeof(cl_float), in);
      bufs.rgb = dev.allocate(capacity * 3 * sizeof(cl_float), CL_MEM_WRITE_ONLY | CL_MEM_ALLOC_HOST_PTR);
      bufs.capacity = capacity;
    }
    cl::Kernel& k = bufs.kernel;
    int arg = 18;
    for (cl::Buffer* b : {&bufs.texels, &bufs.theta_i, &bufs.phi_i, &bufs.theta_v, &bufs.phi_v, &bufs.rgb}) k.setArg(arg++, *b);
    for (size_t first = 0; first < count; first += kChunk) {
      const size_t n = std::min(kChunk, count - first), padded = round_up(n, kPad);
      {
        const cl_map_flags w = CL_MAP_WRITE_INVALIDATE_REGION;
        Mapped<cl_int> texel(queue, bufs.texels, w, padded);
        Mapped<cl_float> ti(queue, bufs.theta_i, w, padded), pi(queue, bufs.phi_i, w, padded);
        Mapped<cl_float> tv(queue, bufs.theta_v, w, padded), pv(queue, bufs.phi_v, w, padded);
        split_over_cores(n, [&](size_t begin, size_t end) {
          for (size_t i = begin; i < end; ++i) {
            const DecodeQuery q = query(first + i);
            if (q.material >= materials) check_material(q.material);  // throws NotFoundError
            texel.get()[i] = texel_code(db_.materials[q.material], bufs.p6_offset[q.material], q.x, q.y);
            ti.get()[i] = float(q.light.theta);
            pi.get()[i] = float(q.light.phi);
            tv.get()[i] = float(q.view.theta);
            pv.get()[i] = float(q.view.phi);
          }
        });
        std::fill(texel.get() + n, texel.get() + padded, -1);
        for (const auto* a : {&ti, &pi, &tv, &pv}) std::fill(a->get() + n, a->get() + padded, 0.0f);
      }
      k.setArg(24, cl_uint(padded));
      // A fixed work-group size: PoCL compiles a kernel once per work-group size it is launched with.
      queue.enqueueNDRangeKernel(k, cl::NullRange, cl::NDRange(padded / kQueriesPerItem), cl::NDRange(kPad / kQueriesPerItem));
      Mapped<cl_float> rgb(queue, bufs.rgb, CL_MAP_READ, 3 * padded);
      const float* r = rgb.get();
      split_over_cores(n, [&](size_t begin, size_t end) {
        for (size_t i = begin; i < end; ++i) out[first + i] = {r[i], r[padded + i], r[2 * padded + i]};
      });
    }
  });
}

}  // namespace btfvq
