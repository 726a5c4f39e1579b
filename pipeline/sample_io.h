#pragma once
// Reading and writing measured samples in the UBO2003 layout (DESIGN.md section 2):
//   a zip or a directory tree (any depth) of images named
//     "NNNNN tlTTT plPPP tvTTT pvPPP.jpg"   (8-bit, sRGB-encoded; running index, then light
//                                             theta/phi and view theta/phi in integer degrees)
//   or "tlTTT_plPPP_tvTTT_pvPPP.png|.exr"    (PNG 8-bit sRGB-encoded, EXR linear float = HDR).
// Angles are parsed from the names, never from the order. Every error names the file.
#include <functional>
#include <string>

#include "pipeline/btf.h"

namespace btfvq {

// Called with (done, total) while images are read or written; may be empty.
using ProgressFn = std::function<void(size_t done, size_t total)>;

struct SampleInfo {
  int width = 0, height = 0;
  size_t views = 0;
  size_t lights_per_view = 0;  // the largest light count of any view
  size_t images = 0;
  Dynamic dynamic = Dynamic::LDR;
  uint64_t raw_bytes = 0;
};

// Loads a zip (by content, not by extension) or a directory. Throws InputError naming the file for:
// unreadable or truncated images, wrong image size, names that do not parse, duplicate or missing
// directions, zip entries with absolute paths or "..".
MeasuredSample load_sample(const std::string& path, const ProgressFn& progress = {});

// Reads only names and one image header: fast.
SampleInfo inspect_sample(const std::string& path);

struct WriteOptions {
  int jpeg_quality = 95;  // LDR images are JPEG, as the real archives
  ProgressFn progress;
};

// Writes the sample in the UBO2003 layout: a .zip path gives a zip, anything else a directory with
// one subfolder per view ("tv030_pv030/00008 tl000 pl000 tv030 pv030.jpg"). HDR samples are written
// as "tl000_pl000_tv030_pv030.exr". The output appears atomically (written under a temporary name,
// renamed when complete).
void write_sample(const MeasuredSample& sample, const std::string& path, const WriteOptions& options = {});

}  // namespace btfvq
