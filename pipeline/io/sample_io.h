#pragma once
// Reading and writing measured samples in the UBO2003 layout (DESIGN.md section 2):
//   a zip or a directory tree (any depth) of images named
//     "NNNNN tlTTT plPPP tvTTT pvPPP.jpg"   (8-bit, sRGB-encoded; running index, then light
//                                             theta/phi and view theta/phi in integer degrees)
//   or "tlTTT_plPPP_tvTTT_pvPPP.png|.exr"    (PNG 8-bit sRGB-encoded, EXR linear float = HDR).
// Angles are parsed from the names, never from the order. Every error names the file.
// Files that are not images (README, .txt, ...) and macOS metadata ("__MACOSX/", "._*") are ignored.
#include <functional>
#include <string>

#include "pipeline/btf.h"

namespace btfvq {

// Called with (done, total) while images are read or written; may be empty. Calls are serialised and
// come from the calling thread; an exception thrown by it (e.g. CancelledError) aborts the operation.
using ProgressFn = std::function<void(size_t done, size_t total)>;

struct SampleInfo {
  int width = 0, height = 0;
  size_t views = 0;
  size_t lights_per_view = 0;  // every view of a valid sample has the same lights
  size_t images = 0;
  Dynamic dynamic = Dynamic::LDR;
  uint64_t raw_bytes = 0;
};

// True when `path` is a directory, or a file whose content is a zip (or tar) archive. Says nothing
// about whether the images inside are valid; throws InputError when the path does not exist.
bool is_sample_path(const std::string& path);

// Loads a zip (by content, not by extension) or a directory. Throws InputError naming the file for:
// unreadable or truncated images, wrong image size or channel count, names that do not parse, mixed
// LDR/HDR, duplicate or missing directions (a sample drawn from the Bonn-81 set must hold all 81 x 81
// pairs), zip entries with absolute paths or "..", an empty input or a path that does not exist.
// max_expanded_bytes > 0 rejects an archive whose entries declare more uncompressed bytes than that
// (zip bombs), and any entry that expands beyond what it declares.
MeasuredSample load_sample(const std::string& path, const ProgressFn& progress = {}, uint64_t max_expanded_bytes = 0);

// Reads only names and one image header: fast. Validates the names as load_sample does.
SampleInfo inspect_sample(const std::string& path, uint64_t max_expanded_bytes = 0);

struct WriteOptions {
  int jpeg_quality = 95;  // LDR images are JPEG, as the real archives
  ProgressFn progress;
};

// Writes the sample in the UBO2003 layout: a .zip path gives a zip, anything else a directory with
// one subfolder per view ("tv030_pv030/00008 tl000 pl000 tv030 pv030.jpg"). HDR samples are written
// as "tv030_pv030/tl000_pl000_tv030_pv030.exr". The output appears atomically (written under a
// temporary name "PATH.tmp-<pid>", renamed when complete). An existing zip file is replaced; an
// existing directory is never overwritten (InputError). Angles must be integer degrees.
void write_sample(const MeasuredSample& sample, const std::string& path, const WriteOptions& options = {});

}  // namespace btfvq
