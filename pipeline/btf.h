#pragma once
// The measured sample: a BTF as it was photographed. Spatial W x H, a list of view directions and,
// per view, a list of light directions. Stored texel-major (all direction pairs of one texel are
// contiguous) because every later stage works per texel.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include <btfvq/directions.h>

namespace btfvq {

enum class Dynamic { LDR, HDR };

class MeasuredSample {
 public:
  MeasuredSample() = default;
  // Allocates storage for the given geometry; values start at zero.
  MeasuredSample(int width, int height, std::vector<Direction> views, std::vector<std::vector<Direction>> lights,
                 Dynamic dynamic);

  int width() const { return width_; }
  int height() const { return height_; }
  size_t texel_count() const { return size_t(width_) * size_t(height_); }
  Dynamic dynamic() const { return dynamic_; }
  bool is_hdr() const { return dynamic_ == Dynamic::HDR; }

  const std::vector<Direction>& views() const { return views_; }
  const std::vector<Direction>& lights(size_t view) const { return lights_[view]; }
  size_t view_count() const { return views_.size(); }
  // Total number of (view, light) pairs, e.g. 6561 for the Bonn sampling.
  size_t pair_count() const { return pair_offset_.back(); }
  // Index of a pair in 0 .. pair_count()-1.
  size_t pair_index(size_t view, size_t light) const { return pair_offset_[view] + light; }
  // Light count of the largest view, and whether every view has the same light list.
  size_t max_lights() const;

  // Value of one colour channel (0 R, 1 G, 2 B). LDR: gamma-encoded 0..255; HDR: linear radiance.
  float value(size_t texel, size_t pair, int channel) const {
    const size_t i = (texel * pair_count() + pair) * 3 + size_t(channel);
    return dynamic_ == Dynamic::LDR ? float(ldr_[i]) : hdr_[i];
  }
  // Raw texel-major storage: (texel * pair_count + pair) * 3 + channel.
  std::vector<uint8_t>& ldr_data() { return ldr_; }
  const std::vector<uint8_t>& ldr_data() const { return ldr_; }
  std::vector<float>& hdr_data() { return hdr_; }
  const std::vector<float>& hdr_data() const { return hdr_; }

  // Raw size as the definition of the compression ratio counts it: W*H*pairs*3 bytes for LDR
  // (8 bits per channel); HDR counts 12 bits per channel, as paper Sec. 6 does (1.8 GB for 256^2).
  uint64_t raw_bytes() const;

 private:
  int width_ = 0, height_ = 0;
  Dynamic dynamic_ = Dynamic::LDR;
  std::vector<Direction> views_;
  std::vector<std::vector<Direction>> lights_;
  std::vector<size_t> pair_offset_{0};
  std::vector<uint8_t> ldr_;
  std::vector<float> hdr_;
};

// The Bonn geometry: 81 views, each with the same 81 lights.
MeasuredSample make_bonn_sample(int width, int height, Dynamic dynamic);

}  // namespace btfvq
