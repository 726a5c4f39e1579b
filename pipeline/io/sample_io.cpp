#include "pipeline/io/sample_io.h"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <archive.h>
#include <archive_entry.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>

#include <btfvq/error.h>
#include "pipeline/util/atomic_file.h"
#include "pipeline/util/parallel.h"

namespace btfvq {

namespace fs = std::filesystem;

namespace {

// Decoding and encoding run on two threads (the machines have two cores). Images move in batches of
// consecutive pairs so that the texel-major scatter/gather touches contiguous runs of memory.
constexpr size_t kThreads = 2;
constexpr size_t kBatch = 64;
constexpr uint64_t kMaxImageBytes = uint64_t(1) << 30;   // one image file larger than this is hostile
constexpr uint64_t kMaxSampleBytes = uint64_t(1) << 36;  // 64 GiB: far beyond 1024^2 x 81^2 LDR (25 GiB)

using Bytes = std::vector<unsigned char>;

std::string quoted(const std::string& s) { return "'" + s + "'"; }

// A thread claims one image at a time (decoding one is long), but one contiguous part of the texels
// for a whole scatter or gather, so that it walks one long run of the store.
const ParallelOptions kPerImage{.threads = kThreads, .grain = 1};
ParallelOptions texel_parts(size_t texels) { return in_parts(texels, kThreads); }

// ---------------------------------------------------------------------------------------------
// Image names.

std::string lower(std::string s) {
  for (auto& c : s) c = char(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

enum class ImageKind { None, LDR, HDR };

ImageKind image_kind(const std::string& filename) {
  const std::string ext = lower(fs::path(filename).extension().string());
  if (ext == ".jpg" || ext == ".jpeg" || ext == ".png") return ImageKind::LDR;
  if (ext == ".exr") return ImageKind::HDR;
  return ImageKind::None;
}

// Integer degrees as they appear in names.
struct Pair {
  int tl = 0, pl = 0, tv = 0, pv = 0;
  auto operator<=>(const Pair&) const = default;
};

std::string pair_label(const Pair& p) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "tl%03d pl%03d tv%03d pv%03d", p.tl, p.pl, p.tv, p.pv);
  return buf;
}

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> parts;
  size_t start = 0;
  for (size_t i = 0; i <= s.size(); ++i)
    if (i == s.size() || s[i] == sep) {
      parts.push_back(s.substr(start, i - start));
      start = i + 1;
    }
  return parts;
}

bool all_digits(const std::string& s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

// "tl045" -> 45; exactly three digits.
std::optional<int> angle_field(const std::string& token, const char* prefix) {
  if (token.size() != 5 || token.compare(0, 2, prefix) != 0 || !all_digits(token.substr(2))) return std::nullopt;
  return std::stoi(token.substr(2));
}

// Parses "NNNNN tlTTT plPPP tvTTT pvPPP" or "tlTTT_plPPP_tvTTT_pvPPP" (the file name without its
// extension). Thetas must lie in [0, 90], phis in [0, 360).
std::optional<Pair> parse_image_name(const std::string& filename) {
  const std::string stem = fs::path(filename).stem().string();
  std::vector<std::string> f = split(stem, ' ');
  if (f.size() == 5 && all_digits(f[0]))
    f.erase(f.begin());
  else
    f = split(stem, '_');
  if (f.size() != 4) return std::nullopt;
  const auto tl = angle_field(f[0], "tl"), pl = angle_field(f[1], "pl");
  const auto tv = angle_field(f[2], "tv"), pv = angle_field(f[3], "pv");
  if (!tl || !pl || !tv || !pv) return std::nullopt;
  if (*tl > 90 || *tv > 90 || *pl >= 360 || *pv >= 360) return std::nullopt;
  return Pair{*tl, *pl, *tv, *pv};
}

// macOS zips carry "__MACOSX/..." and "._name" resource forks that look like images but are not.
bool is_platform_metadata(const std::string& relative) {
  if (fs::path(relative).filename().string().rfind("._", 0) == 0) return true;
  for (const auto& part : split(relative, '/'))
    if (part == "__MACOSX") return true;
  return false;
}

// ---------------------------------------------------------------------------------------------
// Archives (libarchive): zip and tar, recognised by content.

struct ArchiveReader {
  archive* a = nullptr;
  explicit ArchiveReader(const std::string& path) {
    a = archive_read_new();
    // Only formats that hold their data inside the file: never mtree, which refers to files on disk.
    archive_read_support_format_zip(a);
    archive_read_support_format_tar(a);
    archive_read_support_format_gnutar(a);
    archive_read_support_filter_gzip(a);
    archive_read_support_filter_bzip2(a);
    archive_read_support_filter_xz(a);
    archive_read_support_filter_zstd(a);
    if (archive_read_open_filename(a, path.c_str(), 1 << 16) != ARCHIVE_OK) {
      const std::string why = archive_error_string(a) ? archive_error_string(a) : "unknown format";
      archive_read_free(a);
      a = nullptr;
      throw InputError(path + " is not a BTF sample: not a directory and not a zip archive (" + why + ")");
    }
  }
  ~ArchiveReader() {
    if (a) archive_read_free(a);
  }
  ArchiveReader(const ArchiveReader&) = delete;
  ArchiveReader& operator=(const ArchiveReader&) = delete;

  // Next entry, or nullptr at the end.
  archive_entry* next(const std::string& path) {
    archive_entry* e = nullptr;
    const int r = archive_read_next_header(a, &e);
    if (r == ARCHIVE_EOF) return nullptr;
    if (r < ARCHIVE_WARN) throw InputError(path + ": damaged archive: " + error());
    return e;
  }
  std::string error() const { return archive_error_string(a) ? archive_error_string(a) : "unknown error"; }
};

std::string entry_name(archive_entry* e) {
  if (const char* p = archive_entry_pathname(e)) return p;
  if (const char* p = archive_entry_pathname_utf8(e)) return p;
  return "<unnamed entry>";
}

bool escapes_archive(const std::string& name) {
  if (name.empty() || name[0] == '/' || name[0] == '\\') return true;
  if (name.size() >= 2 && name[1] == ':') return true;  // "C:..."
  std::string unified = name;
  std::replace(unified.begin(), unified.end(), '\\', '/');
  for (const auto& part : split(unified, '/'))
    if (part == "..") return true;
  return false;
}

Bytes read_entry_data(ArchiveReader& r, archive_entry* e, const std::string& label) {
  Bytes data;
  if (archive_entry_size_is_set(e)) {
    const auto size = archive_entry_size(e);
    if (size < 0 || uint64_t(size) > kMaxImageBytes) throw InputError(label + ": image entry is implausibly large");
    data.reserve(size_t(size));
  }
  unsigned char buf[1 << 16];
  for (;;) {
    const la_ssize_t n = archive_read_data(r.a, buf, sizeof buf);
    if (n < 0) throw InputError(label + ": cannot read from archive: " + r.error());
    if (n == 0) break;
    data.insert(data.end(), buf, buf + n);
    if (data.size() > kMaxImageBytes) throw InputError(label + ": image entry is implausibly large");
    if (archive_entry_size_is_set(e) && data.size() > uint64_t(std::max<la_int64_t>(archive_entry_size(e), 0)))
      throw InputError(label + ": the entry expands beyond the size it declares; the archive is rejected");
  }
  return data;
}

Bytes read_file(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw InputError(file.string() + ": cannot open image file");
  in.seekg(0, std::ios::end);
  const auto size = in.tellg();
  in.seekg(0);
  if (size < 0 || uint64_t(size) > kMaxImageBytes) throw InputError(file.string() + ": cannot read image file");
  Bytes data(static_cast<size_t>(size));
  if (!in.read(reinterpret_cast<char*>(data.data()), std::streamsize(size)))
    throw InputError(file.string() + ": cannot read image file");
  return data;
}

// ---------------------------------------------------------------------------------------------
// The catalogue: every image of a sample, with its direction pair, before any pixel is read.

struct ImageEntry {
  std::string label;  // what error messages call it: the file path, or "archive:entry"
  fs::path file;      // directories: the file to read
  size_t ordinal = 0; // archives: position of the entry in the archive
  Pair pair;
  ImageKind kind = ImageKind::None;
  size_t pair_index = 0;
};

struct Catalogue {
  std::string source;
  bool archive = false;
  std::vector<ImageEntry> images;  // directories: pair order; archives: archive order
  std::vector<Direction> views, lights;
  Dynamic dynamic = Dynamic::LDR;
  uint64_t expanded_bytes = 0;  // archives: the uncompressed sizes their entries declare
};

void add_image(Catalogue& c, const std::string& relative, const std::string& label, const fs::path& file,
               size_t ordinal) {
  if (is_platform_metadata(relative)) return;
  const ImageKind kind = image_kind(relative);
  if (kind == ImageKind::None) return;
  const auto pair = parse_image_name(relative);
  if (!pair)
    throw InputError(label +
                     ": image name does not parse (expected \"NNNNN tlTTT plPPP tvTTT pvPPP.jpg\" or "
                     "\"tlTTT_plPPP_tvTTT_pvPPP.png|.exr\", integer degrees, theta <= 90, phi < 360)");
  c.images.push_back({label, file, ordinal, *pair, kind, 0});
}

void list_directory(Catalogue& c) {
  std::error_code ec;
  fs::recursive_directory_iterator it(c.source, fs::directory_options::skip_permission_denied, ec), end;
  if (ec) throw InputError(c.source + ": cannot list directory: " + ec.message());
  for (; it != end; it.increment(ec)) {
    if (ec) throw InputError(c.source + ": cannot list directory: " + ec.message());
    if (!it->is_regular_file(ec)) continue;
    const fs::path rel = it->path().lexically_relative(c.source);  // fs::relative resolves links: slow
    add_image(c, rel.generic_string(), it->path().string(), it->path(), 0);
  }
}

void list_archive(Catalogue& c) {
  ArchiveReader r(c.source);
  size_t ordinal = 0;
  // All names are checked before any data is used: one escaping entry rejects the whole archive.
  std::vector<std::pair<std::string, size_t>> files;
  while (archive_entry* e = r.next(c.source)) {
    const std::string name = entry_name(e);
    if (escapes_archive(name))
      throw InputError(c.source + ": archive entry " + quoted(name) +
                       " has an absolute path or '..' component; the archive is rejected");
    if (archive_entry_filetype(e) == AE_IFREG) files.emplace_back(name, ordinal);
    // A zip bomb declares what it will expand to; a lying entry is caught while reading it.
    if (archive_entry_size_is_set(e) && archive_entry_size(e) > 0) c.expanded_bytes += uint64_t(archive_entry_size(e));
    ++ordinal;
  }
  for (const auto& [name, ord] : files) add_image(c, name, c.source + ":" + name, {}, ord);
}

// Sorted geometry, duplicate and completeness checks, and each image's pair index.
void arrange(Catalogue& c) {
  if (c.images.empty())
    throw InputError(c.source + " contains no BTF images (expected names like \"00000 tl000 pl000 tv000 pv000.jpg\")");
  const ImageEntry* ldr = nullptr;
  const ImageEntry* hdr = nullptr;
  for (const auto& im : c.images) {
    const ImageEntry*& first = im.kind == ImageKind::HDR ? hdr : ldr;
    if (!first) first = &im;
  }
  if (ldr && hdr)
    throw InputError(c.source + " mixes LDR and HDR images (" + quoted(ldr->label) + " and " + quoted(hdr->label) + ")");
  c.dynamic = hdr ? Dynamic::HDR : Dynamic::LDR;

  // (theta, phi) pairs order lexicographically, which is the (theta, phi) order of the sample.
  using Angles = std::pair<int, int>;
  std::map<Pair, const ImageEntry*> seen;
  std::set<Angles> views, lights;
  for (const auto& im : c.images) {
    const auto [it, fresh] = seen.emplace(im.pair, &im);
    if (!fresh)
      throw InputError(c.source + ": duplicate direction " + pair_label(im.pair) + " in " + quoted(it->second->label) +
                       " and " + quoted(im.label));
    views.emplace(im.pair.tv, im.pair.pv);
    lights.emplace(im.pair.tl, im.pair.pl);
  }
  std::set<Angles> bonn;
  for (const auto& d : bonn81()) bonn.emplace(int(d.theta), int(d.phi));
  const auto within_bonn = [&](const std::set<Angles>& s) {
    return std::includes(bonn.begin(), bonn.end(), s.begin(), s.end());
  };
  const bool is_bonn = within_bonn(views) && within_bonn(lights);
  if (is_bonn) views = lights = bonn;  // a Bonn sample must be complete: 81 views x 81 lights
  for (const auto& v : views)
    for (const auto& l : lights)
      if (!seen.count(Pair{l.first, l.second, v.first, v.second}))
        throw InputError(c.source + ": missing image for " + pair_label(Pair{l.first, l.second, v.first, v.second}) +
                         (is_bonn ? " (a sample on the Bonn directions needs all 81 views x 81 lights)"
                                  : " (every view needs the same light directions)"));

  std::map<Angles, size_t> view_index, light_index;
  for (const auto& v : views) {
    view_index[v] = c.views.size();
    c.views.push_back({double(v.first), double(v.second)});
  }
  for (const auto& l : lights) {
    light_index[l] = c.lights.size();
    c.lights.push_back({double(l.first), double(l.second)});
  }
  for (auto& im : c.images)
    im.pair_index = view_index[{im.pair.tv, im.pair.pv}] * c.lights.size() + light_index[{im.pair.tl, im.pair.pl}];
  if (!c.archive)  // archives must be read in their own order; files are read in pair order
    std::sort(c.images.begin(), c.images.end(),
              [](const ImageEntry& a, const ImageEntry& b) { return a.pair_index < b.pair_index; });
}

Catalogue catalogue(const std::string& path, uint64_t max_expanded_bytes) {
  Catalogue c;
  c.source = path;
  std::error_code ec;
  const auto status = fs::status(path, ec);
  if (path.empty() || !fs::exists(status)) throw InputError(quoted(path) + " does not exist");
  if (fs::is_directory(status)) {
    list_directory(c);
  } else {
    c.archive = true;
    list_archive(c);
    if (max_expanded_bytes > 0 && c.expanded_bytes > max_expanded_bytes)
      throw InputError(path + ": the archive expands to " + std::to_string(c.expanded_bytes) + " bytes, more than the " +
                       std::to_string(max_expanded_bytes) + " allowed");
  }
  arrange(c);
  return c;
}

Bytes read_archive_image(ArchiveReader& r, size_t& position, const Catalogue& c, const ImageEntry& e) {
  for (;;) {
    archive_entry* ae = r.next(c.source);
    if (!ae) throw InputError(e.label + ": entry vanished from the archive while reading");
    if (position++ == e.ordinal) return read_entry_data(r, ae, e.label);
  }
}

Bytes read_image_bytes(const Catalogue& c, const ImageEntry& e) {
  if (!c.archive) return read_file(e.file);
  ArchiveReader r(c.source);
  size_t position = 0;
  return read_archive_image(r, position, c, e);
}

// ---------------------------------------------------------------------------------------------
// Decoding and encoding with OpenImageIO, in memory where the format plugin takes an IOProxy.

bool output_proxy_supported(const std::string& filename) {
  static std::mutex mutex;
  static std::map<std::string, bool> known;
  const std::string ext = lower(fs::path(filename).extension().string());
  std::lock_guard lock(mutex);
  auto it = known.find(ext);
  if (it != known.end()) return it->second;
  auto out = OIIO::ImageOutput::create("probe" + ext);
  return known[ext] = out && out->supports("ioproxy");
}

// A private temporary file for formats that cannot be read or written from memory; removed with it.
struct TempFile {
  fs::path path;
  explicit TempFile(const std::string& extension) {
    std::string pattern = (fs::temp_directory_path() / ("btfvq-image-XXXXXX" + extension)).string();
    const int fd = ::mkstemps(pattern.data(), int(extension.size()));
    if (fd < 0) throw Error("io_error", "cannot create a temporary file in " + fs::temp_directory_path().string());
    ::close(fd);
    path = pattern;
  }
  ~TempFile() {
    std::error_code ec;
    fs::remove(path, ec);
  }
  TempFile(const TempFile&) = delete;
  TempFile& operator=(const TempFile&) = delete;
};

std::string oiio_error(const std::string& specific) {
  std::string e = specific.empty() ? OIIO::geterror() : specific;
  return e.empty() ? "unknown image error" : e;
}

class OpenImage {
 public:
  OpenImage(const ImageEntry& e, const Bytes& data) : label_(e.label) {
    // In memory first; a plugin without IOProxy support fails to open and gets a private file.
    reader_ = std::make_unique<OIIO::Filesystem::IOMemReader>(data.data(), data.size());
    in_ = OIIO::ImageInput::open(e.label, nullptr, reader_.get());
    if (!in_) {
      const std::string memory_error = OIIO::geterror();
      temp_ = std::make_unique<TempFile>(lower(fs::path(e.label).extension().string()));
      std::ofstream(temp_->path, std::ios::binary)
          .write(reinterpret_cast<const char*>(data.data()), std::streamsize(data.size()));
      in_ = OIIO::ImageInput::open(temp_->path.string());
      if (!in_) {
        OIIO::geterror();  // the file error repeats the memory error under a temporary name
        throw InputError(label_ + ": unreadable image: " + oiio_error(memory_error));
      }
    }
    const auto& s = in_->spec();
    if (!(s.nchannels == 3 || (s.nchannels == 4 && s.alpha_channel == 3)))
      throw InputError(label_ + ": image has " + std::to_string(s.nchannels) + " channels, expected 3 (RGB)");
  }
  int width() const { return in_->spec().width; }
  int height() const { return in_->spec().height; }

  template <class T>
  void read(T* out) {
    const auto type = std::is_same_v<T, float> ? OIIO::TypeDesc::FLOAT : OIIO::TypeDesc::UINT8;
    // A truncated JPEG decodes "successfully" with a grey remainder; only has_error() tells.
    const bool ok = in_->read_image(0, 0, 0, 3, type, out);
    if (!ok || in_->has_error()) throw InputError(label_ + ": unreadable or truncated image: " + oiio_error(in_->geterror()));
  }

 private:
  std::string label_;
  std::unique_ptr<OIIO::Filesystem::IOMemReader> reader_;
  std::unique_ptr<TempFile> temp_;
  std::unique_ptr<OIIO::ImageInput> in_;
};

// Three values, written out: std::copy of 3 elements becomes a memmove call, which dominated loading.
template <class T>
inline void copy_rgb(const T* from, T* to) {
  to[0] = from[0];
  to[1] = from[1];
  to[2] = from[2];
}

// Images of a batch lie one after another in memory. Sizes like 256 x 256 x 3 are multiples of 4 KiB,
// so the batch's images would all map to the same L1 cache sets while a texel is scattered across
// them; one cache line of padding per image staggers them (this made the scatter several times faster).
template <class T>
size_t padded_image_size(size_t texels) {
  constexpr size_t line = 64 / sizeof(T);
  return (texels * 3 + line - 1) / line * line + line;
}

struct Reference {
  std::string label;
  int width = 0, height = 0;
};

Reference first_header(const Catalogue& c) {
  const ImageEntry& e = c.images.front();
  const Bytes data = read_image_bytes(c, e);
  OpenImage image(e, data);
  return {e.label, image.width(), image.height()};
}

template <class T>
void decode(const ImageEntry& e, const Bytes& data, const Reference& ref, T* out) {
  OpenImage image(e, data);
  if (image.width() != ref.width || image.height() != ref.height)
    throw InputError(e.label + ": image is " + std::to_string(image.width()) + " x " + std::to_string(image.height()) +
                     " but " + quoted(ref.label) + " is " + std::to_string(ref.width) + " x " + std::to_string(ref.height));
  image.read(out);
}

// Moves a decoded batch into the texel-major store: texel t of image i goes to store[t][offset[i]].
// The store is far larger than any cache and each texel's run lies ~20 KB from the next, so the
// destination of a texel a few steps ahead is prefetched.
template <class T>
void scatter(const T* __restrict batch, size_t image_stride, size_t count, const size_t* __restrict offset,
             T* __restrict store, size_t texel_stride, size_t t0, size_t t1) {
  const size_t lo = *std::min_element(offset, offset + count), hi = *std::max_element(offset, offset + count) + 3;
  const bool compact = (hi - lo) * sizeof(T) <= 4096;
  constexpr size_t kAhead = 4, kLine = 64 / sizeof(T);
  for (size_t t = t0; t < t1; ++t) {
    if (compact && t + kAhead < t1)
      for (size_t k = lo; k < hi; k += kLine) __builtin_prefetch(store + (t + kAhead) * texel_stride + k, 1);
    T* __restrict texel = store + t * texel_stride;
    const T* __restrict src = batch + t * 3;
    for (size_t i = 0; i < count; ++i) copy_rgb(src + i * image_stride, texel + offset[i]);
  }
}

template <class T>
void load_pixels(const Catalogue& c, const Reference& ref, MeasuredSample& s, std::vector<T>& store,
                 const ProgressFn& progress) {
  const size_t n = c.images.size(), texels = s.texel_count(), pairs = s.pair_count();
  // Images are decoded whole (OpenImageIO's strided decode copies pixel by pixel: far slower), then
  // moved into the texel-major store a batch at a time, so each texel's run is visited once per batch.
  const size_t batch_size = std::min(kBatch, n), image_values = padded_image_size<T>(texels);
  std::vector<T> batch(batch_size * image_values);
  std::vector<Bytes> data(batch_size);
  std::vector<size_t> offset(batch_size);
  std::unique_ptr<ArchiveReader> archive;
  size_t position = 0;
  if (c.archive) archive = std::make_unique<ArchiveReader>(c.source);
  for (size_t start = 0; start < n; start += batch_size) {
    const size_t count = std::min(batch_size, n - start);
    if (archive)  // libarchive reads sequentially: one thread fetches, two decode
      for (size_t i = 0; i < count; ++i) data[i] = read_archive_image(*archive, position, c, c.images[start + i]);
    parallel_for(0, count, [&](size_t i) {
      const ImageEntry& e = c.images[start + i];
      if (!archive) data[i] = read_file(e.file);
      decode(e, data[i], ref, batch.data() + i * image_values);
      data[i] = Bytes();
    }, kPerImage);
    for (size_t i = 0; i < count; ++i) offset[i] = c.images[start + i].pair_index * 3;
    parallel_for(0, texels, [&](size_t t0, size_t t1) {
      scatter(batch.data(), image_values, count, offset.data(), store.data(), pairs * 3, t0, t1);
    }, texel_parts(texels));
    if (progress) progress(start + count, n);
  }
}

uint64_t raw_bytes_of(int width, int height, size_t pairs, Dynamic dynamic) {
  const MeasuredSample one_texel(1, 1, {{0, 0}}, {std::vector<Direction>(1)}, dynamic);
  return one_texel.raw_bytes() * uint64_t(width) * uint64_t(height) * pairs;
}

// ---------------------------------------------------------------------------------------------
// Writing.

std::string three_digits(int v) {
  char b[16];
  std::snprintf(b, sizeof b, "%03d", v);
  return b;
}

int name_degrees(double angle, double upper, bool upper_inclusive, const std::string& what) {
  const bool integer = std::isfinite(angle) && std::round(angle) == angle;
  const bool in_range = angle >= 0 && (upper_inclusive ? angle <= upper : angle < upper);
  if (!integer || !in_range)
    throw InputError("cannot write sample: " + what + " angle " + std::to_string(angle) +
                     " is not an integer number of degrees in [0, " + std::to_string(int(upper)) +
                     (upper_inclusive ? "]" : ")") + " (UBO2003 names hold integer degrees)");
  return int(angle);
}

// Relative names in pair order: "tv030_pv030/00008 tl000 pl000 tv030 pv030.jpg" or the EXR form.
std::vector<std::string> image_names(const MeasuredSample& s) {
  std::vector<std::string> names;
  names.reserve(s.pair_count());
  std::set<std::string> unique;
  for (size_t v = 0; v < s.view_count(); ++v) {
    const int tv = name_degrees(s.views()[v].theta, 90, true, "view theta");
    const int pv = name_degrees(s.views()[v].phi, 360, false, "view phi");
    const std::string folder = "tv" + three_digits(tv) + "_pv" + three_digits(pv) + "/";
    for (size_t l = 0; l < s.lights(v).size(); ++l) {
      const int tl = name_degrees(s.lights(v)[l].theta, 90, true, "light theta");
      const int pl = name_degrees(s.lights(v)[l].phi, 360, false, "light phi");
      const Pair p{tl, pl, tv, pv};
      std::string name;
      if (s.is_hdr()) {
        name = "tl" + three_digits(tl) + "_pl" + three_digits(pl) + "_tv" + three_digits(tv) + "_pv" + three_digits(pv) + ".exr";
      } else {
        char index[32];
        std::snprintf(index, sizeof index, "%05zu ", s.pair_index(v, l));
        name = index + pair_label(p) + ".jpg";
      }
      if (!unique.insert(pair_label(p)).second)
        throw InputError("cannot write sample: direction " + pair_label(p) + " occurs twice");
      names.push_back(folder + name);
    }
  }
  return names;
}

template <class T>
Bytes encode(const std::string& name, const T* pixels, int width, int height, int quality) {
  const bool hdr = std::is_same_v<T, float>;
  OIIO::ImageSpec spec(width, height, 3, hdr ? OIIO::TypeDesc::FLOAT : OIIO::TypeDesc::UINT8);
  if (!hdr) {
    spec.attribute("Compression", "jpeg:" + std::to_string(quality));
    spec.attribute("jpeg:subsampling", "4:4:4");  // keep chroma at full resolution: it is measured data
  }
  const auto type = hdr ? OIIO::TypeDesc::FLOAT : OIIO::TypeDesc::UINT8;
  Bytes out;
  const auto fail = [&](const std::string& why) { return Error("io_error", "cannot encode " + name + ": " + oiio_error(why)); };
  if (output_proxy_supported(name)) {
    OIIO::Filesystem::IOVecOutput proxy(out);
    auto o = OIIO::ImageOutput::create(name, &proxy);
    if (!o || !o->open(name, spec) || !o->write_image(type, pixels) || !o->close())
      throw fail(o ? o->geterror() : std::string());
  } else {
    TempFile temp(lower(fs::path(name).extension().string()));
    auto o = OIIO::ImageOutput::create(temp.path.string());
    if (!o || !o->open(temp.path.string(), spec) || !o->write_image(type, pixels) || !o->close())
      throw fail(o ? o->geterror() : std::string());
    out = read_file(temp.path);
  }
  return out;
}

struct ZipWriter {
  archive* a = nullptr;
  std::string path;
  explicit ZipWriter(const std::string& p) : path(p) {
    a = archive_write_new();
    // JPEG and EXR are compressed already: deflate would cost time and gain nothing.
    if (archive_write_set_format_zip(a) != ARCHIVE_OK || archive_write_set_options(a, "zip:compression=store") != ARCHIVE_OK ||
        archive_write_open_filename(a, path.c_str()) != ARCHIVE_OK) {
      const Error e("io_error", "cannot create " + path + ": " + error());
      archive_write_free(a);
      throw e;
    }
  }
  ~ZipWriter() { archive_write_free(a); }
  ZipWriter(const ZipWriter&) = delete;
  ZipWriter& operator=(const ZipWriter&) = delete;
  std::string error() const { return archive_error_string(a) ? archive_error_string(a) : "unknown error"; }

  void add(const std::string& name, const Bytes& data) {
    std::unique_ptr<archive_entry, void (*)(archive_entry*)> e(archive_entry_new(), archive_entry_free);
    archive_entry_set_pathname(e.get(), name.c_str());
    archive_entry_set_size(e.get(), la_int64_t(data.size()));
    archive_entry_set_filetype(e.get(), AE_IFREG);
    archive_entry_set_perm(e.get(), 0644);
    archive_entry_set_mtime(e.get(), std::time(nullptr), 0);
    if (archive_write_header(a, e.get()) != ARCHIVE_OK ||
        archive_write_data(a, data.data(), data.size()) != la_ssize_t(data.size()))
      throw Error("io_error", "cannot write " + name + " into " + path + ": " + error());
  }
  void close() {
    if (archive_write_close(a) != ARCHIVE_OK) throw Error("io_error", "cannot finish " + path + ": " + error());
  }
};

void write_file(const fs::path& file, const Bytes& data) {
  std::ofstream out(file, std::ios::binary);
  out.write(reinterpret_cast<const char*>(data.data()), std::streamsize(data.size()));
  out.close();
  if (!out) throw Error("io_error", "cannot write " + file.string());
}

// Removes the temporary output unless the write completed.
// The inverse of scatter for a run of consecutive pairs: store[t][i] -> image i, texel t.
template <class T>
void gather(const T* __restrict store, size_t texel_stride, size_t count, T* __restrict batch, size_t image_stride,
            size_t t0, size_t t1) {
  constexpr size_t kAhead = 4, kLine = 64 / sizeof(T);
  for (size_t t = t0; t < t1; ++t) {
    if (t + kAhead < t1)
      for (size_t k = 0; k < count * 3; k += kLine) __builtin_prefetch(store + (t + kAhead) * texel_stride + k, 0);
    const T* __restrict texel = store + t * texel_stride;
    T* __restrict dst = batch + t * 3;
    for (size_t i = 0; i < count; ++i) copy_rgb(texel + i * 3, dst + i * image_stride);
  }
}

template <class T>
void write_images(const MeasuredSample& s, const std::vector<T>& store, const std::vector<std::string>& names,
                  const fs::path& target, bool zip, const WriteOptions& options) {
  const size_t pairs = s.pair_count(), texels = s.texel_count();
  const size_t batch_size = std::min(kBatch, pairs);
  const size_t image_values = padded_image_size<T>(texels);
  std::vector<T> batch(batch_size * image_values);
  std::vector<Bytes> encoded(batch_size);
  std::unique_ptr<ZipWriter> writer;
  if (zip)
    writer = std::make_unique<ZipWriter>(target.string());
  else if (!fs::create_directory(target))
    throw Error("io_error", "cannot create directory " + target.string());
  std::set<std::string> folders;
  for (size_t start = 0; start < pairs; start += batch_size) {
    const size_t count = std::min(batch_size, pairs - start);
    parallel_for(0, texels, [&](size_t t0, size_t t1) {
      gather(store.data() + start * 3, pairs * 3, count, batch.data(), image_values, t0, t1);
    }, texel_parts(texels));
    parallel_for(0, count, [&](size_t i) {
      encoded[i] = encode(names[start + i], batch.data() + i * image_values, s.width(), s.height(), options.jpeg_quality);
    }, kPerImage);
    for (size_t i = 0; i < count; ++i) {
      const std::string& name = names[start + i];
      if (writer) {
        writer->add(name, encoded[i]);
      } else {
        const fs::path file = target / name;
        if (folders.insert(file.parent_path().string()).second) fs::create_directories(file.parent_path());
        write_file(file, encoded[i]);
      }
      encoded[i] = Bytes();
    }
    if (options.progress) options.progress(start + count, pairs);
  }
  if (writer) writer->close();
}

}  // namespace

bool is_sample_path(const std::string& path) {
  std::error_code ec;
  const auto status = fs::status(path, ec);
  if (path.empty() || !fs::exists(status)) throw InputError(quoted(path) + " does not exist");
  if (fs::is_directory(status)) return true;
  if (!fs::is_regular_file(status)) return false;
  try {
    ArchiveReader r(path);
    r.next(path);
    return true;
  } catch (const InputError&) {
    return false;
  }
}

MeasuredSample load_sample(const std::string& path, const ProgressFn& progress, uint64_t max_expanded_bytes) {
  const Catalogue c = catalogue(path, max_expanded_bytes);
  const Reference ref = first_header(c);
  // A hostile header (say 100000 x 100000) must be an input error, not an allocation failure.
  const uint64_t bytes = uint64_t(ref.width) * uint64_t(ref.height) * c.images.size() * 3 *
                         (c.dynamic == Dynamic::HDR ? sizeof(float) : 1);
  if (bytes > kMaxSampleBytes)
    throw InputError(c.images.front().label + ": a " + std::to_string(ref.width) + " x " + std::to_string(ref.height) +
                     " sample of " + std::to_string(c.images.size()) + " images would need " +
                     std::to_string(bytes >> 30) + " GiB in memory; the limit is " +
                     std::to_string(kMaxSampleBytes >> 30) + " GiB");
  MeasuredSample s(ref.width, ref.height, c.views, std::vector<std::vector<Direction>>(c.views.size(), c.lights),
                   c.dynamic);
  if (s.is_hdr())
    load_pixels(c, ref, s, s.hdr_data(), progress);
  else
    load_pixels(c, ref, s, s.ldr_data(), progress);
  return s;
}

SampleInfo inspect_sample(const std::string& path, uint64_t max_expanded_bytes) {
  const Catalogue c = catalogue(path, max_expanded_bytes);
  const Reference ref = first_header(c);
  SampleInfo info;
  info.width = ref.width;
  info.height = ref.height;
  info.views = c.views.size();
  info.lights_per_view = c.lights.size();
  info.images = c.images.size();
  info.dynamic = c.dynamic;
  info.raw_bytes = raw_bytes_of(ref.width, ref.height, c.images.size(), c.dynamic);
  return info;
}

void write_sample(const MeasuredSample& sample, const std::string& path, const WriteOptions& options) {
  if (options.jpeg_quality < 1 || options.jpeg_quality > 100)
    throw InputError("JPEG quality must be in [1, 100] (got " + std::to_string(options.jpeg_quality) + ")");
  if (sample.pair_count() == 0 || sample.texel_count() == 0) throw InputError("cannot write an empty sample to " + path);
  const std::vector<std::string> names = image_names(sample);

  std::string dest = path;
  while (dest.size() > 1 && dest.back() == '/') dest.pop_back();
  if (dest.empty()) throw InputError("no output path given");
  const bool zip = lower(fs::path(dest).extension().string()) == ".zip";
  std::error_code ec;
  const auto status = fs::status(dest, ec);
  if (fs::is_directory(status)) throw InputError(dest + " already exists as a directory; it is not overwritten");
  if (fs::exists(status) && !zip) throw InputError(dest + " already exists; it is not overwritten");
  const fs::path parent = fs::path(dest).parent_path();
  if (!parent.empty() && !fs::is_directory(parent)) throw InputError("output directory " + parent.string() + " does not exist");

  AtomicFile out(dest);
  if (sample.is_hdr())
    write_images(sample, sample.hdr_data(), names, out.temp_path(), zip, options);
  else
    write_images(sample, sample.ldr_data(), names, out.temp_path(), zip, options);
  out.commit();
}

}  // namespace btfvq
