#pragma once
// Resampling of a measured sample onto the (phi_v, theta_v, alpha, beta) grid (paper Sec. 4.1),
// as a fixed sparse linear operator built once per sample geometry and grid (docs/resampling.md).
//
// Two local RBF steps, as the paper:
//  1. light step: for every measured view v (a "slot"; a view at theta 0 has one slot per output
//     phi_v node, because its own azimuth is meaningless) and every (alpha, beta) node, interpolate
//     over the k_l measured lights of v nearest to from_onion(alpha, beta, phi of v);
//  2. view step: for every output (phi_v, theta_v) node, interpolate the slots of the k_v measured
//     views nearest to that view direction, at the same (alpha, beta).
// Each step's weights are the Lagrange weights of a local Gaussian RBF interpolant with a polynomial
// term (constant, or linear in a tangent-plane chart): they reproduce the data at measured
// directions and sum to 1, so constants (and, with the linear term, linear functions) pass exactly.
//
// Output per texel: 3 x grid.samples() floats, [channel][AngularGrid::index(phi_v, theta_v, alpha,
// beta)], channels in the coding space of colour.h (converted before interpolation; luminance is
// clamped at 0 afterwards because extrapolation toward the horizon may undershoot).
#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <vector>

#include "pipeline/btf.h"
#include "pipeline/util/config.h"
#include "pipeline/parametrization.h"

namespace btfvq {

// The "resample" section of configs/pipeline.json (the members carry no values of their own).
struct ResampleSettings {
  int light_neighbours = 0;     // k_l: measured lights per (view, alpha, beta) node
  int view_neighbours = 0;      // k_v: measured views per output view node
  double kernel_width_deg = 0;  // Gaussian exp(-(d / width)^2), d great-circle (chart) distance
  int polynomial_degree = 0;    // 0: constant precision; 1: linear precision in the tangent plane
  int tile_texels = 0;          // texels per device batch (small: the batch's data stays in cache)
  // A node beyond the measured range (view or light theta above every measured one) whose share of
  // the decoder's interpolation weight over the measured pairs is at most this times the average
  // node's is "unseen" and copies its nearest seen node (negative: off).
  double unseen_influence = 0;

  // Reads the "resample" section (keys as above) of a pipeline configuration.
  static ResampleSettings from(const ParameterDictionary& config);
  static ResampleSettings defaults();  // from(the shipped configs/pipeline.json)
};

// The "grid" section of a pipeline configuration: the angular grid texels are resampled onto.
AngularGrid grid_settings(const ParameterDictionary& config);
// The "grid" section that grid_settings reads back as `g`.
nlohmann::json grid_section(const AngularGrid& g);

// One entry of a sparse row: a column index (a measured pair, or a slot) and its weight.
struct SparseEntry {
  uint32_t index = 0;
  float weight = 0;
};

class ResampleOperator {
 public:
  // Builds the weights for the geometry (views, lights per view) of `geometry`; its values are not
  // read. Throws InputError if the geometry is empty or settings are out of range.
  ResampleOperator(const MeasuredSample& geometry, const AngularGrid& grid, const ResampleSettings& settings);
  ~ResampleOperator();
  ResampleOperator(const ResampleOperator&) = delete;
  ResampleOperator& operator=(const ResampleOperator&) = delete;

  const AngularGrid& grid() const { return grid_; }
  size_t values_per_texel() const { return 3 * grid_.samples(); }

  // Resamples texels [first_texel, first_texel + count) into out[count * values_per_texel()].
  // Throws InputError if the sample's directions differ from the geometry the operator was built
  // for or the texel range is outside the sample. Dispatches on ComputeDevice::get().backend().
  void apply(const MeasuredSample& sample, size_t first_texel, size_t count, float* out) const;
  void apply_reference(const MeasuredSample& sample, size_t first_texel, size_t count, float* out) const;
  void apply_opencl(const MeasuredSample& sample, size_t first_texel, size_t count, float* out) const;

  // The composite weights of one output node (AngularGrid::index) over measured pairs, duplicates
  // merged: what apply() computes for each channel before the luminance clamp.
  std::vector<SparseEntry> node_weights(size_t node) const;

  // Which nodes copy another (AngularGrid::index of the source per node, itself when seen).
  const std::vector<uint32_t>& node_source() const { return node_source_; }

 private:
  struct DeviceBuffers;
  void check_input(const MeasuredSample& sample, size_t first_texel, size_t count) const;
  void fill_unseen();
  DeviceBuffers device_buffers() const;  // uploads the operator once per OpenCL context

  AngularGrid grid_;
  ResampleSettings settings_;
  std::vector<Direction> views_;
  std::vector<std::vector<Direction>> lights_;
  size_t pair_count_ = 0;
  size_t slot_count_ = 0;
  // Light step: slot_count_ * n_ab rows of light_width_ entries (padded with weight 0).
  int light_width_ = 0;
  std::vector<SparseEntry> light_rows_;
  // View step: n_phi_v * n_theta_v rows of view_width_ slot entries.
  int view_width_ = 0;
  std::vector<SparseEntry> view_rows_;
  std::vector<uint32_t> node_source_;

  mutable std::mutex device_mutex_;
  mutable std::unique_ptr<DeviceBuffers> device_;
};

}  // namespace btfvq
