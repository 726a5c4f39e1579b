#include "pipeline/btf.h"

#include <algorithm>

#include <btfvq/error.h>

namespace btfvq {

MeasuredSample::MeasuredSample(int width, int height, std::vector<Direction> views,
                               std::vector<std::vector<Direction>> lights, Dynamic dynamic)
    : width_(width), height_(height), dynamic_(dynamic), views_(std::move(views)), lights_(std::move(lights)) {
  if (width <= 0 || height <= 0) throw InputError("sample size must be positive");
  if (views_.size() != lights_.size()) throw InputError("every view needs its list of light directions");
  for (const auto& l : lights_) pair_offset_.push_back(pair_offset_.back() + l.size());
  const size_t n = texel_count() * pair_count() * 3;
  if (dynamic_ == Dynamic::LDR)
    ldr_.assign(n, 0);
  else
    hdr_.assign(n, 0.0f);
}

size_t MeasuredSample::max_lights() const {
  size_t m = 0;
  for (const auto& l : lights_) m = std::max(m, l.size());
  return m;
}

uint64_t MeasuredSample::raw_bytes() const {
  const uint64_t channels = uint64_t(texel_count()) * pair_count() * 3;
  return dynamic_ == Dynamic::LDR ? channels : channels * 3 / 2;
}

MeasuredSample make_bonn_sample(int width, int height, Dynamic dynamic) {
  const auto& d = bonn81();
  return MeasuredSample(width, height, d, std::vector<std::vector<Direction>>(d.size(), d), dynamic);
}

}  // namespace btfvq
