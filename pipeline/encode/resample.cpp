#include "pipeline/encode/resample.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <map>
#include <string>

#include <btfvq/colour.h>
#include <btfvq/error.h>
#include "pipeline/runtime/opencl_runtime.h"

namespace btfvq {

ResampleSettings ResampleSettings::from(const ParameterDictionary& config) {
  ResampleSettings s;
  s.light_neighbours = config.integer("resample.light_neighbours", 1, 64);
  s.view_neighbours = config.integer("resample.view_neighbours", 1, 64);
  s.kernel_width_deg = config.number("resample.kernel_width_deg", 0.5, 180.0);
  s.polynomial_degree = config.integer("resample.polynomial_degree", 0, 1);
  s.tile_texels = config.integer("resample.tile_texels", 1, 65536);
  s.unseen_influence = config.number("resample.unseen_influence", -1.0, 1.0);
  return s;
}

AngularGrid grid_settings(const ParameterDictionary& config) {
  AngularGrid g{config.integer("grid.n_beta", 3, 1024), config.integer("grid.n_alpha", 2, 1024),
                config.integer("grid.n_theta_v", 2, 1024), config.integer("grid.n_phi_v", 1, 1024)};
  g.validate();
  return g;
}

nlohmann::json grid_section(const AngularGrid& g) {
  return {{"n_beta", g.n_beta}, {"n_alpha", g.n_alpha}, {"n_theta_v", g.n_theta_v}, {"n_phi_v", g.n_phi_v}};
}

ResampleSettings ResampleSettings::defaults() { return from(ParameterDictionary::embedded_default("pipeline")); }

namespace {

constexpr double kPoleTheta = 1e-9;  // a measured view this close to the normal has no azimuth

double dot(const Vec3& a, const Vec3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
Vec3 normalised(const Vec3& v) {
  const double l = std::sqrt(dot(v, v));
  return {v.x / l, v.y / l, v.z / l};
}

// Azimuthal equidistant chart around q: great-circle distances from q are kept exactly, so the
// interpolant sees the sphere locally as a plane without distorting the nearest-neighbour order.
struct Chart {
  Vec3 q, e1, e2;
  explicit Chart(const Vec3& centre) : q(centre) {
    const Vec3 helper = std::abs(q.z) < 0.9 ? Vec3{0, 0, 1} : Vec3{1, 0, 0};
    e1 = normalised(cross(helper, q));
    e2 = cross(q, e1);
  }
  std::pair<double, double> operator()(const Vec3& p) const {
    const double c = std::clamp(dot(q, p), -1.0, 1.0);
    const double d = std::acos(c);
    const Vec3 t{p.x - c * q.x, p.y - c * q.y, p.z - c * q.z};
    const double s = std::sqrt(dot(t, t));
    if (s < 1e-15) return {0.0, 0.0};
    return {d * dot(t, e1) / s, d * dot(t, e2) / s};
  }
};

// Solves A x = b in place (Gaussian elimination, partial pivoting). False if A is singular.
bool solve(std::vector<double>& a, std::vector<double>& b, size_t n) {
  double scale = 0;
  for (double v : a) scale = std::max(scale, std::abs(v));
  for (size_t col = 0; col < n; ++col) {
    size_t piv = col;
    for (size_t r = col + 1; r < n; ++r)
      if (std::abs(a[r * n + col]) > std::abs(a[piv * n + col])) piv = r;
    if (std::abs(a[piv * n + col]) <= 1e-12 * scale) return false;
    if (piv != col) {
      for (size_t c = 0; c < n; ++c) std::swap(a[col * n + c], a[piv * n + c]);
      std::swap(b[col], b[piv]);
    }
    for (size_t r = col + 1; r < n; ++r) {
      const double f = a[r * n + col] / a[col * n + col];
      if (f == 0) continue;
      for (size_t c = col; c < n; ++c) a[r * n + c] -= f * a[col * n + c];
      b[r] -= f * b[col];
    }
  }
  for (size_t col = n; col-- > 0;) {
    double s = b[col];
    for (size_t c = col + 1; c < n; ++c) s -= a[col * n + c] * b[c];
    b[col] = s / a[col * n + col];
  }
  return true;
}

// Lagrange weights of the local RBF interpolant s(x) = sum_i c_i phi(|x - x_i|) + p(x) with
// sum_i c_i q(x_i) = 0 for every polynomial q of the given degree: the weights w solve
// [Phi P; P^T 0] [w; mu] = [phi(|x_q - x_i|); q(x_q)], so sum w = 1 and polynomials pass exactly.
bool rbf_weights(const std::vector<std::pair<double, double>>& pts, double width, int degree, std::vector<double>& w) {
  const size_t n = pts.size(), m = degree == 0 ? 1 : 3, dim = n + m;
  if (degree == 1 && n < 3) return false;
  auto phi = [&](double dx, double dy) { return std::exp(-(dx * dx + dy * dy) / (width * width)); };
  std::vector<double> a(dim * dim, 0.0), b(dim, 0.0);
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = 0; j < n; ++j) a[i * dim + j] = phi(pts[i].first - pts[j].first, pts[i].second - pts[j].second);
    // Polynomial columns in units of the kernel width keep the system balanced.
    const double poly[3] = {1.0, pts[i].first / width, pts[i].second / width};
    for (size_t k = 0; k < m; ++k) a[i * dim + n + k] = a[(n + k) * dim + i] = poly[k];
    b[i] = phi(pts[i].first, pts[i].second);  // the query is the chart's origin
  }
  b[n] = 1.0;  // polynomial basis at the origin: (1, 0, 0)
  if (!solve(a, b, dim)) return false;
  w.assign(b.begin(), b.begin() + long(n));
  for (double v : w)
    if (!std::isfinite(v)) return false;
  return true;
}

// Weights of the k directions of `candidates` nearest to `query` (ties: lower index first), as
// sparse entries whose float weights sum to 1 as exactly as floats allow.
std::vector<SparseEntry> local_rbf(const Direction& query, const std::vector<Direction>& candidates, int k,
                                   const ResampleSettings& s) {
  std::vector<std::pair<double, uint32_t>> by_angle;
  by_angle.reserve(candidates.size());
  for (size_t i = 0; i < candidates.size(); ++i)
    by_angle.push_back({angle_between(query, candidates[i]), uint32_t(i)});
  const size_t n = std::min(size_t(k), by_angle.size());
  std::partial_sort(by_angle.begin(), by_angle.begin() + long(n), by_angle.end());
  by_angle.resize(n);

  const Chart chart(to_vector(query));
  std::vector<std::pair<double, double>> pts;
  for (const auto& [angle, i] : by_angle) pts.push_back(chart(to_vector(candidates[i])));

  std::vector<double> w;
  const double width = s.kernel_width_deg * kDeg;
  // Collinear neighbours (or too few) cannot carry a linear term; duplicates nothing: nearest.
  bool ok = s.polynomial_degree == 1 && rbf_weights(pts, width, 1, w);
  if (!ok) ok = rbf_weights(pts, width, 0, w);
  if (!ok) {
    w.assign(n, 0.0);
    w[0] = 1.0;
  }
  // Round to float, then put the rounding residue on the largest weight so the sum stays 1.
  std::vector<SparseEntry> row;
  double sum = 0;
  size_t largest = 0;
  for (size_t i = 0; i < n; ++i) {
    row.push_back({by_angle[i].second, float(w[i])});
    sum += double(row.back().weight);
    if (std::abs(w[i]) > std::abs(w[largest])) largest = i;
  }
  row[largest].weight = float(double(row[largest].weight) + (1.0 - sum));
  return row;
}

void pad(std::vector<SparseEntry>& row, int width) { row.resize(size_t(width), SparseEntry{0, 0.0f}); }

void add_cell(std::vector<double>& w, const Cell& c, double weight, size_t stride, size_t offset) {
  w[offset + size_t(c.i0) * stride] += weight * (1 - c.w);
  w[offset + size_t(c.i1) * stride] += weight * c.w;
}

// Share of the decoder's interpolation weight (docs/btfbase-format.md: linear in phi_v, theta_v,
// alpha; beta's cubic Hermite counted by its linear cell) that each view node and each (alpha,
// beta) node receives over the measured pairs, relative to the average node (1 = average).
struct Influence {
  std::vector<double> view, light;
};

Influence influence(const AngularGrid& g, const std::vector<Direction>& views,
                    const std::vector<std::vector<Direction>>& lights) {
  Influence in;
  in.view.assign(size_t(g.n_phi_v) * size_t(g.n_theta_v), 0.0);
  in.light.assign(g.slice2(), 0.0);
  for (size_t v = 0; v < views.size(); ++v) {
    const Cell t = g.theta_v_cell(views[v].theta);
    const size_t nt = size_t(g.n_theta_v);
    if (views[v].theta < kPoleTheta) {  // no azimuth: every phi_v node alike
      for (int p = 0; p < g.n_phi_v; ++p) add_cell(in.view, t, 1.0 / g.n_phi_v, 1, size_t(p) * nt);
    } else {
      const Cell ph = g.phi_v_cell(views[v].phi);
      add_cell(in.view, t, 1 - ph.w, 1, size_t(ph.i0) * nt);
      add_cell(in.view, t, ph.w, 1, size_t(ph.i1) * nt);
    }
    for (const Direction& l : lights[v]) {
      const OnionAngles o = to_onion(l, views[v].phi);
      const Cell a = g.alpha_cell(o.alpha), b = g.beta_cell(o.beta);
      add_cell(in.light, b, 1 - a.w, 1, size_t(a.i0) * size_t(g.n_beta));
      add_cell(in.light, b, a.w, 1, size_t(a.i1) * size_t(g.n_beta));
    }
  }
  for (auto* w : {&in.view, &in.light}) {
    double sum = 0;
    for (double x : *w) sum += x;
    for (double& x : *w) x = sum > 0 ? x * double(w->size()) / sum : 0;
  }
  return in;
}

// For every node, the nearest node (by the angle between `direction`s) that is not `unseen`; itself
// when it is not. All nodes stay their own when every one is unseen.
std::vector<uint32_t> nearest_seen(const std::vector<bool>& unseen, const std::function<Vec3(size_t)>& direction) {
  std::vector<uint32_t> source(unseen.size());
  for (size_t n = 0; n < unseen.size(); ++n) {
    source[n] = uint32_t(n);
    if (!unseen[n]) continue;
    double best = -2;
    for (size_t m = 0; m < unseen.size(); ++m)
      if (!unseen[m]) {
        const double c = dot(direction(n), direction(m));
        if (c > best + 1e-12) best = c, source[n] = uint32_t(m);
      }
  }
  return source;
}

}  // namespace

ResampleOperator::ResampleOperator(const MeasuredSample& geometry, const AngularGrid& grid,
                                   const ResampleSettings& settings)
    : grid_(grid), settings_(settings), views_(geometry.views()) {
  grid_.validate();
  if (settings_.light_neighbours < 1 || settings_.view_neighbours < 1 || !(settings_.kernel_width_deg > 0) ||
      settings_.polynomial_degree < 0 || settings_.polynomial_degree > 1 || settings_.tile_texels < 1)
    throw InputError("resample settings out of range (neighbours >= 1, kernel_width_deg > 0, polynomial_degree 0 or 1)");
  if (views_.empty()) throw InputError("cannot resample a sample without view directions");
  for (size_t v = 0; v < views_.size(); ++v) {
    lights_.push_back(geometry.lights(v));
    if (lights_.back().empty()) throw InputError("view " + std::to_string(v) + " of the sample has no light directions");
  }
  pair_count_ = geometry.pair_count();

  // Slots: one per measured view, n_phi_v for a view at the pole (its light frame follows the
  // output node's azimuth instead of its own).
  std::vector<size_t> first_slot(views_.size());
  for (size_t v = 0; v < views_.size(); ++v) {
    first_slot[v] = slot_count_;
    slot_count_ += views_[v].theta < kPoleTheta ? size_t(grid_.n_phi_v) : 1;
  }

  const size_t n_ab = grid_.slice2();
  light_width_ = 0;
  for (const auto& l : lights_) light_width_ = std::max(light_width_, std::min(settings_.light_neighbours, int(l.size())));
  light_rows_.resize(slot_count_ * n_ab * size_t(light_width_));
  for (size_t v = 0; v < views_.size(); ++v) {
    const bool pole = views_[v].theta < kPoleTheta;
    for (int p = 0; p < (pole ? grid_.n_phi_v : 1); ++p) {
      const double frame_phi = pole ? grid_.phi_v_node(p) : views_[v].phi;
      const size_t slot = first_slot[v] + size_t(p);
      for (int a = 0; a < grid_.n_alpha; ++a)
        for (int b = 0; b < grid_.n_beta; ++b) {
          const Direction light = from_onion({grid_.alpha_node(a), grid_.beta_node(b)}, frame_phi);
          auto row = local_rbf(light, lights_[v], settings_.light_neighbours, settings_);
          for (auto& e : row) e.index = uint32_t(geometry.pair_index(v, e.index));
          pad(row, light_width_);
          std::copy(row.begin(), row.end(),
                    light_rows_.begin() + long((slot * n_ab + size_t(a) * size_t(grid_.n_beta) + size_t(b)) *
                                               size_t(light_width_)));
        }
    }
  }

  view_width_ = std::min(settings_.view_neighbours, int(views_.size()));
  for (int p = 0; p < grid_.n_phi_v; ++p)
    for (int t = 0; t < grid_.n_theta_v; ++t) {
      auto row = local_rbf({grid_.theta_v_node(t), grid_.phi_v_node(p)}, views_, settings_.view_neighbours, settings_);
      for (auto& e : row) e.index = uint32_t(first_slot[e.index] + (views_[e.index].theta < kPoleTheta ? size_t(p) : 0));
      view_rows_.insert(view_rows_.end(), row.begin(), row.end());
    }
  fill_unseen();
}

// Nodes beyond the measured range (the theta_v = 90 plane when the views stop at 75; the light
// horizon) hold the interpolant's extrapolation: invented values, yet the encoder compares them like
// any other and pays entries for them. Those the decoder hardly reads at a measured direction repeat
// their nearest seen node instead, by copying that node's operator rows, so the device and reference
// paths stay one operator. Nodes inside the measured range are never copied, even where no measured
// direction falls in their cells (the view nodes between the six views at theta 15): there the
// interpolant is what a renderer's query between measured views reads.
void ResampleOperator::fill_unseen() {
  const size_t n_ab = grid_.slice2(), view_nodes = grid_.samples() / n_ab;
  node_source_.resize(grid_.samples());
  for (size_t i = 0; i < node_source_.size(); ++i) node_source_[i] = uint32_t(i);
  if (settings_.unseen_influence < 0) return;
  const Influence in = influence(grid_, views_, lights_);
  const double floor = std::max(settings_.unseen_influence, 1e-9), margin = 1e-6;
  double view_theta = 0, light_theta = 0;
  for (size_t v = 0; v < views_.size(); ++v) {
    view_theta = std::max(view_theta, views_[v].theta);
    for (const Direction& l : lights_[v]) light_theta = std::max(light_theta, l.theta);
  }
  auto view_direction = [&](size_t n) {
    return Direction{grid_.theta_v_node(int(n % size_t(grid_.n_theta_v))), grid_.phi_v_node(int(n / size_t(grid_.n_theta_v)))};
  };
  auto light_direction = [&](size_t n) {
    return from_onion({grid_.alpha_node(int(n / size_t(grid_.n_beta))), grid_.beta_node(int(n % size_t(grid_.n_beta)))}, 0.0);
  };
  std::vector<bool> view_unseen(view_nodes), light_unseen(n_ab);
  for (size_t n = 0; n < view_nodes; ++n) view_unseen[n] = in.view[n] <= floor && view_direction(n).theta > view_theta + margin;
  for (size_t n = 0; n < n_ab; ++n) light_unseen[n] = in.light[n] <= floor && light_direction(n).theta > light_theta + margin;
  const auto view_src = nearest_seen(view_unseen, [&](size_t n) { return to_vector(view_direction(n)); });
  const auto light_src = nearest_seen(light_unseen, [&](size_t n) { return to_vector(light_direction(n)); });
  const size_t lw = size_t(light_width_), vw = size_t(view_width_);
  for (size_t slot = 0; slot < slot_count_; ++slot)
    for (size_t ab = 0; ab < n_ab; ++ab)
      if (light_src[ab] != ab)
        std::copy_n(light_rows_.begin() + long((slot * n_ab + light_src[ab]) * lw), lw,
                    light_rows_.begin() + long((slot * n_ab + ab) * lw));
  for (size_t vn = 0; vn < view_nodes; ++vn)
    if (view_src[vn] != vn)
      std::copy_n(view_rows_.begin() + long(view_src[vn] * vw), vw, view_rows_.begin() + long(vn * vw));
  for (size_t vn = 0; vn < view_nodes; ++vn)
    for (size_t ab = 0; ab < n_ab; ++ab) node_source_[vn * n_ab + ab] = uint32_t(view_src[vn] * n_ab + light_src[ab]);
}

ResampleOperator::~ResampleOperator() = default;

std::vector<SparseEntry> ResampleOperator::node_weights(size_t node) const {
  if (node >= grid_.samples()) throw InputError("output node " + std::to_string(node) + " is outside the grid");
  const size_t n_ab = grid_.slice2(), view_node = node / n_ab, ab = node % n_ab;
  std::map<uint32_t, double> acc;
  for (int i = 0; i < view_width_; ++i) {
    const SparseEntry& ve = view_rows_[view_node * size_t(view_width_) + size_t(i)];
    const SparseEntry* lrow = &light_rows_[(size_t(ve.index) * n_ab + ab) * size_t(light_width_)];
    for (int j = 0; j < light_width_; ++j)
      if (lrow[j].weight != 0.0f) acc[lrow[j].index] += double(ve.weight) * double(lrow[j].weight);
  }
  std::vector<SparseEntry> out;
  for (const auto& [pair, w] : acc) out.push_back({pair, float(w)});
  return out;
}

void ResampleOperator::check_input(const MeasuredSample& sample, size_t first_texel, size_t count) const {
  bool same = sample.views() == views_;
  for (size_t v = 0; same && v < views_.size(); ++v) same = sample.lights(v) == lights_[v];
  if (!same)
    throw InputError("sample directions differ from the geometry the resampling operator was built for (" +
                     std::to_string(sample.view_count()) + " views, " + std::to_string(sample.pair_count()) +
                     " pairs vs " + std::to_string(views_.size()) + " views, " + std::to_string(pair_count_) +
                     " pairs)");
  if (first_texel > sample.texel_count() || count > sample.texel_count() - first_texel)
    throw InputError("texel range " + std::to_string(first_texel) + " + " + std::to_string(count) +
                     " is outside the sample of " + std::to_string(sample.texel_count()) + " texels");
}

void ResampleOperator::apply(const MeasuredSample& sample, size_t first_texel, size_t count, float* out) const {
  if (ComputeDevice::get().uses_opencl()) apply_opencl(sample, first_texel, count, out);
  else apply_reference(sample, first_texel, count, out);
}

void ResampleOperator::apply_reference(const MeasuredSample& sample, size_t first_texel, size_t count,
                                       float* out) const {
  check_input(sample, first_texel, count);
  const size_t n_ab = grid_.slice2(), samples = grid_.samples(), view_nodes = samples / n_ab;
  std::vector<Lab3> lab(pair_count_);
  std::vector<Lab3> slots(slot_count_ * n_ab);
  for (size_t t = 0; t < count; ++t) {
    const size_t texel = first_texel + t;
    for (size_t p = 0; p < pair_count_; ++p)
      lab[p] = to_coding_space({sample.value(texel, p, 0), sample.value(texel, p, 1), sample.value(texel, p, 2)},
                               sample.is_hdr());
    // Light step: every slot's (alpha, beta) slice.
    for (size_t r = 0; r < slots.size(); ++r) {
      const SparseEntry* row = &light_rows_[r * size_t(light_width_)];
      Lab3 s;
      for (int j = 0; j < light_width_; ++j) {
        const Lab3& v = lab[row[j].index];
        s.l += row[j].weight * v.l;
        s.a += row[j].weight * v.a;
        s.b += row[j].weight * v.b;
      }
      slots[r] = s;
    }
    // View step: every output node from the same (alpha, beta) of its views' slots.
    float* o = out + t * 3 * samples;
    for (size_t vn = 0; vn < view_nodes; ++vn)
      for (size_t ab = 0; ab < n_ab; ++ab) {
        Lab3 s;
        for (int i = 0; i < view_width_; ++i) {
          const SparseEntry& e = view_rows_[vn * size_t(view_width_) + size_t(i)];
          const Lab3& v = slots[size_t(e.index) * n_ab + ab];
          s.l += e.weight * v.l;
          s.a += e.weight * v.a;
          s.b += e.weight * v.b;
        }
        const size_t node = vn * n_ab + ab;
        o[node] = std::max(s.l, 0.0f);
        o[samples + node] = s.a;
        o[2 * samples + node] = s.b;
      }
  }
}

struct ResampleOperator::DeviceBuffers {
  cl::Context context;  // held, so that a re-created device can be told apart from this one
  cl::Buffer light_rows, view_rows;
};

ResampleOperator::DeviceBuffers ResampleOperator::device_buffers() const {
  std::lock_guard<std::mutex> lock(device_mutex_);
  auto& dev = ComputeDevice::get();
  if (!device_ || device_->context() != dev.context()()) {
    auto d = std::make_unique<DeviceBuffers>();
    d->context = dev.context();
    d->light_rows = dev.upload(light_rows_);
    d->view_rows = dev.upload(view_rows_);
    device_ = std::move(d);
  }
  return *device_;
}

void ResampleOperator::apply_opencl(const MeasuredSample& sample, size_t first_texel, size_t count, float* out) const {
  check_input(sample, first_texel, count);
  if (count == 0) return;
  auto& dev = ComputeDevice::get();
  const DeviceBuffers ops = device_buffers();  // a copy: OpenCL objects are reference counted
  const size_t n_ab = grid_.slice2(), samples = grid_.samples(), view_nodes = samples / n_ab;
  // Work-items handle octets of 8 texels (float8); a tile is a whole number of octets.
  const size_t tile = round_up(std::min(count, size_t(settings_.tile_texels)), 8);
  const bool hdr = sample.is_hdr();
  const size_t in_bytes_per_texel = pair_count_ * 3 * (hdr ? sizeof(float) : sizeof(uint8_t));

  opencl_call("resampling a tile of texels", [&] {
    cl::CommandQueue& queue = dev.queue();
    cl::Buffer input = dev.allocate(tile * in_bytes_per_texel, CL_MEM_READ_ONLY);
    cl::Buffer lab = dev.allocate(tile * pair_count_ * 3 * sizeof(float));
    cl::Buffer slots = dev.allocate(tile * slot_count_ * n_ab * 3 * sizeof(float));
    cl::Buffer output = dev.allocate(tile * 3 * samples * sizeof(float), CL_MEM_WRITE_ONLY);
    cl::Kernel convert = dev.kernel("resample.cl", hdr ? "convert_hdr" : "convert_ldr");
    cl::Kernel light = dev.kernel("resample.cl", "light_step");
    cl::Kernel view = dev.kernel("resample.cl", "view_step");
    convert.setArg(0, input);
    convert.setArg(1, lab);
    convert.setArg(3, cl_uint(pair_count_));
    light.setArg(0, lab);
    light.setArg(1, ops.light_rows);
    light.setArg(2, cl_uint(light_width_));
    light.setArg(3, cl_uint(n_ab));
    light.setArg(4, cl_uint(pair_count_));
    light.setArg(5, cl_uint(slot_count_));
    light.setArg(6, slots);
    view.setArg(0, slots);
    view.setArg(1, ops.view_rows);
    view.setArg(2, cl_uint(view_width_));
    view.setArg(3, cl_uint(n_ab));
    view.setArg(4, cl_uint(slot_count_));
    view.setArg(6, cl_uint(samples));
    view.setArg(7, output);
    for (size_t done = 0; done < count; done += tile) {
      const size_t n = std::min(tile, count - done), octets = (n + 7) / 8, texel = first_texel + done;
      const void* src = hdr ? static_cast<const void*>(sample.hdr_data().data() + texel * pair_count_ * 3)
                            : static_cast<const void*>(sample.ldr_data().data() + texel * pair_count_ * 3);
      queue.enqueueWriteBuffer(input, CL_FALSE, 0, n * in_bytes_per_texel, src);
      convert.setArg(2, cl_uint(n));
      view.setArg(5, cl_uint(n));
      queue.enqueueNDRangeKernel(convert, cl::NullRange, cl::NDRange(pair_count_, octets));
      queue.enqueueNDRangeKernel(light, cl::NullRange, cl::NDRange(slot_count_, octets));
      queue.enqueueNDRangeKernel(view, cl::NullRange, cl::NDRange(view_nodes, octets));
      queue.enqueueReadBuffer(output, CL_TRUE, 0, n * 3 * samples * sizeof(float), out + done * 3 * samples);
    }
  });
}

}  // namespace btfvq
