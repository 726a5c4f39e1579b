#include "pipeline/decoder.h"

#include <algorithm>
#include <cmath>

#include "pipeline/error.h"
#include "pipeline/opencl_runtime.h"
#include "pipeline/parametrization.h"

namespace btfvq {

namespace {

// The cubic Hermite of FORMAT.md step 4 inside beta cell i at parameter t. The weights depend only
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
  cl::Buffer p1, c, i1, i2, p2_index, p2_scale, m, p3_index, p3_scale, p4_index, p4_scale;
  cl::Buffer p6_index, p6_scale, materials;
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

Rgb Decoder::evaluate_p4(uint32_t p4_row, bool hdr, const Direction& light, const Direction& view) const {
  if (!(light.theta <= 90.0 && view.theta <= 90.0) || !std::isfinite(light.phi) || !std::isfinite(view.phi)) return {};
  const AngularGrid& grid = db_.codebooks.grid;

  // Steps 1-3: onion angles of the light for this view azimuth (to_onion of parametrization.h, with
  // sin(beta) = x and cos(beta) = sqrt(1 - x^2) instead of two more trigonometric calls), and the
  // four interpolation cells.
  const double phi = relative_light_azimuth(light.phi, view.phi) * kDeg, sin_t = std::sin(light.theta * kDeg);
  const double sb = std::clamp(std::cos(phi) * sin_t, -1.0, 1.0), ly = std::sin(phi) * sin_t;
  const double cos_b = std::sqrt(1.0 - sb * sb);
  const OnionAngles onion{cos_b > 0 ? std::asin(std::clamp(ly / cos_b, -1.0, 1.0)) / kDeg : 0.0, std::asin(sb) / kDeg};
  const int bi = std::clamp(int(std::floor((sb + 1.0) / 2.0 * (nb_ - 1))), 0, nb_ - 2);
  const double bw = std::clamp((onion.beta - beta_nodes_[size_t(bi)]) / (beta_nodes_[size_t(bi) + 1] - beta_nodes_[size_t(bi)]), 0.0, 1.0);
  const Cell ac = grid.alpha_cell(onion.alpha);
  const Cell tc = grid.theta_v_cell(view.theta);
  const Cell pc = grid.phi_v_cell(view.phi);
  const Hermite hermite(bi, bw, nb_);
  const int alpha_node[2] = {ac.i0, ac.i1};
  const double alpha_w[2] = {1.0 - ac.w, ac.w};
  const size_t beta0 = size_t(bi), beta1 = size_t(bi) + 1;

  // Step 5: one M entry -> RGB.
  auto decode_m = [&](uint32_t mi) {
    const uint32_t* me = m_ + size_t(mi) * 2;
    const size_t p2 = size_t(me[0]) * size_t(na_), i2 = size_t(me[1]) * size_t(na_);
    double yy = 0, cb = 0, cr = 0;
    for (int a = 0; a < 2; ++a) {
      const size_t an = size_t(alpha_node[a]);
      const double w = alpha_w[a];
      yy += w * double(p2_scale_[p2 + an]) * hermite(p1_ + size_t(p2_index_[p2 + an]) * size_t(nb_));
      const uint32_t* i1 = i1_ + size_t(i2_[i2 + an]) * size_t(nb_);
      const float* c0 = c_ + size_t(i1[beta0]) * 2;
      const float* c1 = c_ + size_t(i1[beta1]) * 2;
      cb += w * ((1.0 - bw) * double(c0[0]) + bw * double(c1[0]));
      cr += w * ((1.0 - bw) * double(c0[1]) + bw * double(c1[1]));
    }
    return from_coding_space({float(yy), float(cb), float(cr)}, hdr);
  };

  // Step 6: P4 over phi_v (wrapping), P3 over theta_v, each node with its own scale; then P6.
  const int phi_node[2] = {pc.i0, pc.i1};
  const double phi_w[2] = {1.0 - pc.w, pc.w};
  const int theta_node[2] = {tc.i0, tc.i1};
  const double theta_w[2] = {tc.i0 == tc.i1 ? 1.0 : 1.0 - tc.w, tc.i0 == tc.i1 ? 0.0 : tc.w};
  double r = 0, g = 0, b = 0;
  const size_t p4 = size_t(p4_row) * np_;
  for (int p = 0; p < 2; ++p) {
    if (phi_w[p] == 0.0) continue;
    const size_t pn = size_t(phi_node[p]);
    const size_t p3 = size_t(p4_index_[p4 + pn]) * nt_;
    const double s4 = phi_w[p] * double(p4_scale_[p4 + pn]);
    for (int t = 0; t < 2; ++t) {
      if (theta_w[t] == 0.0) continue;
      const size_t tn = size_t(theta_node[t]);
      const double s = s4 * theta_w[t] * double(p3_scale_[p3 + tn]);
      const Rgb v = decode_m(p3_index_[p3 + tn]);
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
    bufs->p2_index = upload_nonempty(dev, k.p2_index.data());
    bufs->p2_scale = upload_nonempty(dev, k.p2_scale.data());
    bufs->m = upload_nonempty(dev, k.m.data());
    bufs->p3_index = upload_nonempty(dev, k.p3_index.data());
    bufs->p3_scale = upload_nonempty(dev, k.p3_scale.data());
    bufs->p4_index = upload_nonempty(dev, k.p4_index.data());
    bufs->p4_scale = upload_nonempty(dev, k.p4_scale.data());
    // All materials' P6 concatenated; per material (offset, width, height, hdr).
    std::vector<int32_t> p6i;
    std::vector<float> p6s;
    std::vector<cl_int> table;
    for (const auto& mat : db_.materials) {
      table.insert(table.end(), {cl_int(p6i.size()), cl_int(mat.width), cl_int(mat.height), cl_int(mat.dynamic == Dynamic::HDR)});
      p6i.insert(p6i.end(), mat.p6_index.begin(), mat.p6_index.end());
      p6s.insert(p6s.end(), mat.p6_scale.begin(), mat.p6_scale.end());
    }
    bufs->p6_index = upload_nonempty(dev, p6i);
    bufs->p6_scale = upload_nonempty(dev, p6s);
    bufs->materials = upload_nonempty(dev, table);
  });
  device_ = std::move(bufs);
  return *device_;
}

std::vector<Rgb> Decoder::decode_opencl(const std::vector<DecodeQuery>& queries) const {
  auto& dev = ComputeDevice::get();
  if (!dev.uses_opencl()) throw DeviceError("decode_opencl: OpenCL is not in use (" + dev.description() + ")");
  for (const auto& q : queries) check_material(q.material);
  std::vector<Rgb> out(queries.size());
  if (queries.empty()) return out;
  DeviceBuffers& bufs = device_buffers();
  const AngularGrid& g = db_.codebooks.grid;
  constexpr size_t kChunk = size_t(1) << 20;  // bounds the query buffers for very large batches
  for (size_t first = 0; first < queries.size(); first += kChunk) {
    const size_t n = std::min(kChunk, queries.size() - first);
    std::vector<cl_int> texel(n * 4);
    std::vector<cl_float> angles(n * 4);
    for (size_t i = 0; i < n; ++i) {
      const DecodeQuery& q = queries[first + i];
      texel[i * 4 + 0] = cl_int(q.material);
      texel[i * 4 + 1] = q.x;
      texel[i * 4 + 2] = q.y;
      texel[i * 4 + 3] = 0;
      angles[i * 4 + 0] = float(q.light.theta);
      angles[i * 4 + 1] = float(q.light.phi);
      angles[i * 4 + 2] = float(q.view.theta);
      angles[i * 4 + 3] = float(q.view.phi);
    }
    std::vector<cl_float> rgb(n * 3);
    opencl_call("decode kernel", [&] {
      cl::Buffer bt = dev.upload(texel), ba = dev.upload(angles);
      cl::Buffer bo = dev.allocate(rgb.size() * sizeof(cl_float), CL_MEM_WRITE_ONLY);
      cl::Kernel k = dev.kernel("decode.cl", "decode_batch");
      int arg = 0;
      for (cl::Buffer* b : {&bufs.p1, &bufs.c, &bufs.i1, &bufs.i2, &bufs.p2_index, &bufs.p2_scale, &bufs.m, &bufs.p3_index,
                            &bufs.p3_scale, &bufs.p4_index, &bufs.p4_scale, &bufs.p6_index, &bufs.p6_scale, &bufs.materials})
        k.setArg(arg++, *b);
      k.setArg(arg++, cl_int(g.n_beta));
      k.setArg(arg++, cl_int(g.n_alpha));
      k.setArg(arg++, cl_int(g.n_theta_v));
      k.setArg(arg++, cl_int(g.n_phi_v));
      k.setArg(arg++, bt);
      k.setArg(arg++, ba);
      k.setArg(arg++, bo);
      k.setArg(arg++, cl_uint(n));
      dev.queue().enqueueNDRangeKernel(k, cl::NullRange, cl::NDRange(round_up(n, 64)));
      dev.download(bo, rgb);
    });
    for (size_t i = 0; i < n; ++i) out[first + i] = {rgb[i * 3], rgb[i * 3 + 1], rgb[i * 3 + 2]};
  }
  return out;
}

}  // namespace btfvq
