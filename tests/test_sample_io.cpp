#include <OpenImageIO/imageio.h>
#include <archive.h>
#include <archive_entry.h>
#include <doctest/doctest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <btfvq/directions.h>
#include <btfvq/error.h>
#include "pipeline/io/sample_io.h"
#include "support/test_paths.h"

using namespace btfvq;
namespace fs = std::filesystem;

namespace {

constexpr int kSize = 8;

// Smooth within each image (so that JPEG keeps it), different for every pair and channel.
uint8_t pattern(size_t texel, size_t pair, int channel) {
  const size_t x = texel % kSize, y = texel / kSize;
  return uint8_t(30 + 10 * x + 8 * y + size_t(channel) * 25 + pair % 31);
}

MeasuredSample bonn_test_sample() {
  MeasuredSample s = make_bonn_sample(kSize, kSize, Dynamic::LDR);
  for (size_t t = 0; t < s.texel_count(); ++t)
    for (size_t p = 0; p < s.pair_count(); ++p)
      for (int c = 0; c < 3; ++c) s.ldr_data()[(t * s.pair_count() + p) * 3 + size_t(c)] = pattern(t, p, c);
  return s;
}

// A small sample off the Bonn set: 2 views x 3 lights, deliberately listed out of (theta, phi) order.
const std::vector<Direction> kViews{{20, 90}, {10, 0}};
const std::vector<Direction> kLights{{80, 359}, {5, 0}, {40, 200}};

float hdr_value(int x, int y, const Direction& view, const Direction& light, int c) {
  return 0.001f * float(x) + 0.37f * float(y) + float(view.theta) * 0.5f + float(light.phi) * 0.25f + float(c) * 3.5f +
         1e-7f;
}

void write_image(const fs::path& file, int width, int height, int channels, const void* data, OIIO::TypeDesc type) {
  auto out = OIIO::ImageOutput::create(file.string());
  REQUIRE(out);
  OIIO::ImageSpec spec(width, height, channels, type);
  if (file.extension() == ".jpg") spec.attribute("Compression", "jpeg:100");
  REQUIRE(out->open(file.string(), spec));
  REQUIRE(out->write_image(type, data));
  REQUIRE(out->close());
}

void write_zip(const fs::path& zip, const std::vector<std::pair<std::string, std::string>>& entries) {
  archive* a = archive_write_new();
  REQUIRE(archive_write_set_format_zip(a) == ARCHIVE_OK);
  REQUIRE(archive_write_open_filename(a, zip.string().c_str()) == ARCHIVE_OK);
  for (const auto& [name, data] : entries) {
    archive_entry* e = archive_entry_new();
    archive_entry_set_pathname(e, name.c_str());
    archive_entry_set_size(e, la_int64_t(data.size()));
    archive_entry_set_filetype(e, AE_IFREG);
    archive_entry_set_perm(e, 0644);
    REQUIRE(archive_write_header(a, e) == ARCHIVE_OK);
    REQUIRE(archive_write_data(a, data.data(), data.size()) == la_ssize_t(data.size()));
    archive_entry_free(e);
  }
  REQUIRE(archive_write_close(a) == ARCHIVE_OK);
  archive_write_free(a);
}

// The Bonn sample written once per test process as a directory; error tests damage copies of it.
const fs::path& written_directory() {
  static const fs::path dir = [] {
    const fs::path d = test::scratch_dir("written") / "sample";
    write_sample(bonn_test_sample(), d.string(), {100, {}});
    return d;
  }();
  return dir;
}

// The same sample written once as a zip.
const fs::path& written_zip() {
  static const fs::path zip = [] {
    const fs::path z = test::scratch_dir("writtenzip") / "sample.zip";
    write_sample(bonn_test_sample(), z.string(), {100, {}});
    return z;
  }();
  return zip;
}

// A copy made of hard links (cheap); a test that damages a file must unlink it first (fresh_file).
fs::path copy_of_written(const std::string& name) {
  const fs::path d = test::scratch_dir(name) / "sample";
  fs::copy(written_directory(), d, fs::copy_options::recursive | fs::copy_options::create_hard_links);
  return d;
}

// Unlinks `file` (shared with the written sample) and returns its former content.
std::string fresh_file(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  std::string content(std::istreambuf_iterator<char>(in), {});
  fs::remove(file);
  return content;
}

// Pair (view 8 = (30, 30), light 0 = (0, 0)) of the Bonn order: index 8 * 81.
const char* const kView30Light0 = "tv030_pv030/00648 tl000 pl000 tv030 pv030.jpg";
const char* const kEarlyImage = "tv000_pv000/00003 tl015 pl120 tv000 pv000.jpg";

// Asserts that loading throws InputError whose message contains `needle`.
void check_load_error(const fs::path& path, const std::string& needle) {
  try {
    load_sample(path.string());
    FAIL("expected InputError for " << path);
  } catch (const InputError& e) {
    INFO("message: " << std::string(e.what()));
    CHECK(std::string(e.what()).find(needle) != std::string::npos);
  }
}

void check_same_geometry(const MeasuredSample& s) {
  REQUIRE(s.view_count() == 81);
  CHECK(s.views() == bonn81());
  for (size_t v = 0; v < 81; ++v) CHECK(s.lights(v) == bonn81());
  CHECK(s.width() == kSize);
  CHECK(s.height() == kSize);
}

double mean_abs_error(const MeasuredSample& a, const MeasuredSample& b, int* max_error) {
  REQUIRE(a.ldr_data().size() == b.ldr_data().size());
  double sum = 0;
  *max_error = 0;
  for (size_t i = 0; i < a.ldr_data().size(); ++i) {
    const int d = std::abs(int(a.ldr_data()[i]) - int(b.ldr_data()[i]));
    sum += d;
    *max_error = std::max(*max_error, d);
  }
  return sum / double(a.ldr_data().size());
}

}  // namespace

TEST_CASE("a Bonn sample written as a zip and as a directory loads back within JPEG tolerance") {
  const MeasuredSample original = bonn_test_sample();
  const fs::path dir = test::scratch_dir("roundtrip");
  size_t last_done = 0, last_total = 0;
  WriteOptions options{100, [&](size_t done, size_t total) { last_done = done, last_total = total; }};
  write_sample(original, (dir / "s.zip").string(), options);
  CHECK(last_done == 6561);
  CHECK(last_total == 6561);
  // Atomic writes leave nothing but their output behind.
  size_t entries = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir)) ++entries;
  CHECK(entries == 1);

  for (const fs::path& path : {dir / "s.zip", written_directory()}) {
    INFO(path);
    size_t loaded_done = 0, loaded_total = 0;
    const MeasuredSample loaded =
        load_sample(path.string(), [&](size_t done, size_t total) { loaded_done = done, loaded_total = total; });
    CHECK(loaded_done == 6561);
    CHECK(loaded_total == 6561);
    check_same_geometry(loaded);
    CHECK(loaded.dynamic() == Dynamic::LDR);
    int max_error = 0;
    CHECK(mean_abs_error(original, loaded, &max_error) < 1.0);
    CHECK(max_error <= 8);
  }
}

TEST_CASE("the directory layout is UBO2003's: per-view subfolders, running index in pair order") {
  const fs::path& d = written_directory();
  CHECK(fs::is_regular_file(d / kView30Light0));
  CHECK(fs::is_regular_file(d / "tv000_pv000/00000 tl000 pl000 tv000 pv000.jpg"));
  CHECK(fs::is_regular_file(d / "tv075_pv345/06560 tl075 pl345 tv075 pv345.jpg"));
  size_t folders = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(d)) ++folders;
  CHECK(folders == 81);
}

TEST_CASE("a real-layout tree loads at any depth, ignores other files and the running index") {
  const fs::path root = test::scratch_dir("reallayout");
  const fs::path d = root / "UBO_TEST256" / "images";
  fs::create_directories(d.parent_path());
  fs::copy(written_directory(), d, fs::copy_options::recursive);
  std::ofstream(root / "README") << "a measured BTF\n";
  std::ofstream(d / "tv000_pv000" / "notes.txt") << "not an image\n";
  // The running index does not decide the direction: renumber one file.
  fs::rename(d / kView30Light0, d / "tv030_pv030/77777 tl000 pl000 tv030 pv030.jpg");
  const MeasuredSample loaded = load_sample(root.string());
  check_same_geometry(loaded);
  const MeasuredSample reference = load_sample(written_directory().string());
  CHECK(loaded.ldr_data() == reference.ldr_data());
}

TEST_CASE("a zip is recognised by its content, not by its extension") {
  const fs::path dir = test::scratch_dir("bycontent");
  fs::copy_file(written_zip(), dir / "sample.dat");
  check_same_geometry(load_sample((dir / "sample.dat").string()));
  const SampleInfo info = inspect_sample((dir / "sample.dat").string());
  CHECK(info.width == kSize);
  CHECK(info.height == kSize);
  CHECK(info.views == 81);
  CHECK(info.lights_per_view == 81);
  CHECK(info.images == 6561);
  CHECK(info.dynamic == Dynamic::LDR);
  CHECK(info.raw_bytes == uint64_t(kSize) * kSize * 6561 * 3);
}

TEST_CASE("zip entries are stored, not deflated") {
  const fs::path zip = written_zip();
  archive* a = archive_read_new();
  archive_read_support_format_zip(a);
  REQUIRE(archive_read_open_filename(a, zip.string().c_str(), 1 << 16) == ARCHIVE_OK);
  archive_entry* e = nullptr;
  size_t entries = 0, bytes = 0;
  std::string first;
  while (archive_read_next_header(a, &e) == ARCHIVE_OK) {
    if (entries++ == 0) first = archive_entry_pathname(e);
    bytes += size_t(archive_entry_size(e));
  }
  archive_read_free(a);
  CHECK(entries == 6561);
  CHECK(first == "tv000_pv000/00000 tl000 pl000 tv000 pv000.jpg");
  // Stored: the archive is the images plus small headers (deflate would make it smaller than that).
  CHECK(fs::file_size(zip) > bytes);
}

TEST_CASE("PNG-named samples load exactly, off the Bonn set, sorted by (theta, phi)") {
  const fs::path d = test::scratch_dir("png");
  for (const auto& v : kViews)
    for (const auto& l : kLights) {
      std::vector<uint8_t> px(kSize * kSize * 3);
      for (int i = 0; i < kSize * kSize * 3; ++i) px[size_t(i)] = uint8_t(i + int(v.theta) + int(l.phi) / 2);
      char name[64];
      std::snprintf(name, sizeof name, "tl%03d_pl%03d_tv%03d_pv%03d.png", int(l.theta), int(l.phi), int(v.theta), int(v.phi));
      write_image(d / name, kSize, kSize, 3, px.data(), OIIO::TypeDesc::UINT8);
    }
  const MeasuredSample s = load_sample(d.string());
  CHECK(s.dynamic() == Dynamic::LDR);
  REQUIRE(s.view_count() == 2);
  CHECK(s.views()[0] == Direction{10, 0});
  CHECK(s.views()[1] == Direction{20, 90});
  REQUIRE(s.lights(0).size() == 3);
  CHECK(s.lights(0)[0] == Direction{5, 0});
  CHECK(s.lights(0)[1] == Direction{40, 200});
  CHECK(s.lights(0)[2] == Direction{80, 359});
  // Texel 5, channel 1, view (20, 90), light (40, 200): i = 5 * 3 + 1.
  CHECK(s.value(5, s.pair_index(1, 1), 1) == float(uint8_t(16 + 20 + 100)));
  CHECK(s.value(0, s.pair_index(0, 2), 0) == float(uint8_t(0 + 10 + 179)));
}

TEST_CASE("EXR-named samples load as HDR with exact float values") {
  const fs::path d = test::scratch_dir("exr") / "deep" / "er";
  fs::create_directories(d);
  for (const auto& v : kViews)
    for (const auto& l : kLights) {
      std::vector<float> px;
      for (int y = 0; y < kSize; ++y)
        for (int x = 0; x < kSize; ++x)
          for (int c = 0; c < 3; ++c) px.push_back(hdr_value(x, y, v, l, c));
      char name[64];
      std::snprintf(name, sizeof name, "tl%03d_pl%03d_tv%03d_pv%03d.exr", int(l.theta), int(l.phi), int(v.theta), int(v.phi));
      write_image(d / name, kSize, kSize, 3, px.data(), OIIO::TypeDesc::FLOAT);
    }
  const MeasuredSample s = load_sample(d.parent_path().string());
  CHECK(s.is_hdr());
  REQUIRE(s.view_count() == 2);
  const Direction view = s.views()[1], light = s.lights(1)[2];
  CHECK(view == Direction{20, 90});
  CHECK(light == Direction{80, 359});
  CHECK(s.value(3 * kSize + 7, s.pair_index(1, 2), 2) == hdr_value(7, 3, view, light, 2));
  size_t exact = 0;
  for (size_t v = 0; v < 2; ++v)
    for (size_t l = 0; l < 3; ++l)
      for (int y = 0; y < kSize; ++y)
        for (int x = 0; x < kSize; ++x)
          for (int c = 0; c < 3; ++c)
            exact += s.value(size_t(y * kSize + x), s.pair_index(v, l), c) == hdr_value(x, y, s.views()[v], s.lights(v)[l], c);
  CHECK(exact == 2 * 3 * kSize * kSize * 3);

  // And an HDR sample survives write_sample (EXR, float) exactly, as a zip.
  const fs::path zip = test::scratch_dir("exrzip") / "h.zip";
  write_sample(s, zip.string());
  const MeasuredSample back = load_sample(zip.string());
  CHECK(back.is_hdr());
  CHECK(back.views() == s.views());
  CHECK(back.hdr_data() == s.hdr_data());
}

TEST_CASE("a truncated JPEG is an error naming it") {
  const fs::path d = copy_of_written("truncated");
  const std::string jpeg = fresh_file(d / kEarlyImage);
  std::ofstream(d / kEarlyImage, std::ios::binary) << jpeg.substr(0, jpeg.size() / 2);
  check_load_error(d, "00003 tl015 pl120 tv000 pv000.jpg");
}

TEST_CASE("a truncated JPEG inside a zip is an error naming the entry") {
  const fs::path dir = test::scratch_dir("truncatedzip");
  const std::string good = test::file_bytes(written_directory() / "tv000_pv000/00000 tl000 pl000 tv000 pv000.jpg");
  write_zip(dir / "t.zip", {{"a/tl000_pl000_tv010_pv000.jpg", good}, {"a/tl000_pl000_tv020_pv000.jpg", good.substr(0, good.size() / 2)}});
  check_load_error(dir / "t.zip", "a/tl000_pl000_tv020_pv000.jpg");
}

TEST_CASE("an image of another size is an error naming it") {
  const fs::path d = copy_of_written("wrongsize");
  std::vector<uint8_t> px(4 * 4 * 3, 100);
  fresh_file(d / kEarlyImage);
  write_image(d / kEarlyImage, 4, 4, 3, px.data(), OIIO::TypeDesc::UINT8);
  check_load_error(d, "00003 tl015 pl120 tv000 pv000.jpg");
}

TEST_CASE("a grey image (wrong channel count) is an error naming it") {
  const fs::path d = copy_of_written("channels");
  std::vector<uint8_t> px(kSize * kSize, 100);
  fresh_file(d / kEarlyImage);
  write_image(d / kEarlyImage, kSize, kSize, 1, px.data(), OIIO::TypeDesc::UINT8);
  check_load_error(d, "00003 tl015 pl120 tv000 pv000.jpg");
}

TEST_CASE("a duplicate direction is an error naming the file") {
  const fs::path d = copy_of_written("duplicate");
  fs::copy_file(d / kView30Light0, d / "tv000_pv000/99999 tl000 pl000 tv030 pv030.jpg");
  check_load_error(d, "99999 tl000 pl000 tv030 pv030.jpg");
  check_load_error(d, "duplicate");
}

TEST_CASE("a missing direction of a Bonn sample names the pair") {
  const fs::path d = copy_of_written("missing");
  fs::remove(d / kView30Light0);
  check_load_error(d, "tl000 pl000 tv030 pv030");
}

TEST_CASE("off the Bonn set, every view needs the same lights") {
  const fs::path d = test::scratch_dir("missingoff");
  std::vector<uint8_t> px(kSize * kSize * 3, 7);
  for (const char* name : {"tl005_pl000_tv010_pv000.png", "tl040_pl200_tv010_pv000.png", "tl005_pl000_tv020_pv090.png"})
    write_image(d / name, kSize, kSize, 3, px.data(), OIIO::TypeDesc::UINT8);
  check_load_error(d, "tl040 pl200 tv020 pv090");
}

TEST_CASE("an image name that does not parse is an error naming it") {
  const fs::path d = copy_of_written("unparsable");
  fs::copy_file(d / kView30Light0, d / "tv030_pv030/00001 tl000 pl000 tv030.jpg");
  check_load_error(d, "00001 tl000 pl000 tv030.jpg");
  fs::remove(d / "tv030_pv030/00001 tl000 pl000 tv030.jpg");
  fs::copy_file(d / kView30Light0, d / "tv030_pv030/00001 tl100 pl000 tv030 pv030.jpg");  // theta > 90
  check_load_error(d, "00001 tl100 pl000 tv030 pv030.jpg");
}

TEST_CASE("mixed LDR and HDR images are an error naming both") {
  const fs::path d = test::scratch_dir("mixed");
  std::vector<uint8_t> px(kSize * kSize * 3, 7);
  std::vector<float> fx(kSize * kSize * 3, 0.5f);
  write_image(d / "tl005_pl000_tv010_pv000.png", kSize, kSize, 3, px.data(), OIIO::TypeDesc::UINT8);
  write_image(d / "tl040_pl200_tv010_pv000.exr", kSize, kSize, 3, fx.data(), OIIO::TypeDesc::FLOAT);
  check_load_error(d, "tl005_pl000_tv010_pv000.png");
  check_load_error(d, "tl040_pl200_tv010_pv000.exr");
}

TEST_CASE("zip entries with '..' or absolute paths reject the whole archive") {
  const fs::path dir = test::scratch_dir("evil");
  const std::string good = test::file_bytes(written_directory() / "tv000_pv000/00000 tl000 pl000 tv000 pv000.jpg");
  write_zip(dir / "dotdot.zip", {{"x/tl000_pl000_tv000_pv000.jpg", good}, {"../evil.jpg", good}});
  write_zip(dir / "abs.zip", {{"x/tl000_pl000_tv000_pv000.jpg", good}, {"/abs.jpg", good}});
  write_zip(dir / "inner.zip", {{"x/tl000_pl000_tv000_pv000.jpg", good}, {"x/../../evil.txt", "not even an image"}});
  check_load_error(dir / "dotdot.zip", "../evil.jpg");
  check_load_error(dir / "abs.zip", "/abs.jpg");
  check_load_error(dir / "inner.zip", "x/../../evil.txt");
  CHECK_THROWS_AS(inspect_sample((dir / "dotdot.zip").string()), InputError);
}

TEST_CASE("a path that does not exist is an error naming it") {
  const fs::path nowhere = test::scratch_dir("nowhere") / "no-such-sample.zip";
  check_load_error(nowhere, "no-such-sample.zip");
  CHECK_THROWS_AS(inspect_sample(nowhere.string()), InputError);
}

TEST_CASE("an empty directory or a directory without images is an error naming it") {
  const fs::path d = test::scratch_dir("empty") / "emptysample";
  fs::create_directories(d);
  check_load_error(d, "emptysample");
  std::ofstream(d / "README.txt") << "nothing here\n";
  check_load_error(d, "emptysample");
}

TEST_CASE("a file that is neither a directory nor an archive is not a sample") {
  const fs::path d = test::scratch_dir("notasample");
  std::ofstream(d / "notes.txt") << "just text\n";
  CHECK_FALSE(is_sample_path((d / "notes.txt").string()));
  check_load_error(d / "notes.txt", "notes.txt");
  CHECK(is_sample_path(d.string()));
}

TEST_CASE("write_sample rejects non-integer angles and existing directories, leaving nothing behind") {
  const fs::path dir = test::scratch_dir("writeerrors");
  MeasuredSample odd(2, 2, {{10.5, 0}}, {{{0, 0}}}, Dynamic::LDR);
  CHECK_THROWS_AS(write_sample(odd, (dir / "odd.zip").string()), InputError);
  MeasuredSample wrapped(2, 2, {{10, 360}}, {{{0, 0}}}, Dynamic::LDR);
  CHECK_THROWS_AS(write_sample(wrapped, (dir / "wrapped").string()), InputError);
  fs::create_directories(dir / "existing");
  std::ofstream(dir / "existing" / "keep.txt") << "mine\n";
  MeasuredSample fine(2, 2, {{10, 0}}, {{{0, 0}}}, Dynamic::LDR);
  CHECK_THROWS_AS(write_sample(fine, (dir / "existing").string()), InputError);
  CHECK_THROWS_AS(write_sample(fine, (dir / "x.zip").string(), {0, {}}), InputError);
  CHECK_THROWS_AS(write_sample(fine, (dir / "no" / "such" / "parent.zip").string()), InputError);
  size_t entries = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir)) ++entries;
  CHECK(entries == 1);
  CHECK(fs::exists(dir / "existing" / "keep.txt"));
}

TEST_CASE("`btfvq info` describes a written zip") {
  const fs::path dir = test::scratch_dir("info");
  std::string out;
  const int status = test::run_command("'" + (test::bin_dir() / "btfvq").string() + "' info '" + written_zip().string() + "'", &out);
  INFO(out);
  CHECK(status == 0);
  CHECK(out.find("8 x 8") != std::string::npos);
  CHECK(out.find("81 views x 81 lights") != std::string::npos);
  CHECK(out.find("LDR") != std::string::npos);
  CHECK(out.find("6561") != std::string::npos);
  CHECK(out.find("1,259,712") != std::string::npos);  // 8 * 8 * 6561 * 3 raw bytes

  std::ofstream(dir / "notes.txt") << "just text\n";
  const int bad = test::run_command("'" + (test::bin_dir() / "btfvq").string() + "' info '" + (dir / "notes.txt").string() + "'", &out);
  CHECK(bad == 2);
  CHECK(out.find("nor a BTF sample") != std::string::npos);
}

namespace {

uint32_t crc32(const std::string& bytes) {
  uint32_t c = 0xFFFFFFFFu;
  for (unsigned char b : bytes) {
    c ^= b;
    for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
  }
  return ~c;
}

std::string big_endian(uint32_t v) {
  return {char(v >> 24), char((v >> 16) & 0xFF), char((v >> 8) & 0xFF), char(v & 0xFF)};
}

// A PNG whose header claims width x height pixels but holds (almost) no pixel data.
std::string png_header_only(uint32_t width, uint32_t height) {
  const std::string ihdr = "IHDR" + big_endian(width) + big_endian(height) + std::string("\x08\x02\x00\x00\x00", 5);
  const std::string idat = "IDAT\x78\x9c", iend = "IEND";  // the start of a zlib stream, then nothing
  return std::string("\x89PNG\r\n\x1a\n", 8) + big_endian(13) + ihdr + big_endian(crc32(ihdr)) + big_endian(2) + idat +
         big_endian(crc32(idat)) + big_endian(0) + iend + big_endian(crc32(iend));
}

}  // namespace

TEST_CASE("an image header claiming a gigantic size is an input error, not an allocation failure") {
  const fs::path d = test::scratch_dir("huge");
  std::ofstream(d / "tl010_pl000_tv010_pv000.png", std::ios::binary) << png_header_only(200000, 200000);
  check_load_error(d, "tl010_pl000_tv010_pv000.png");
  check_load_error(d, "GiB");
  // A plausible size with no pixel data behind it is a truncated image.
  const fs::path e = test::scratch_dir("nodata");
  std::ofstream(e / "tl010_pl000_tv010_pv000.png", std::ios::binary) << png_header_only(8, 8);
  check_load_error(e, "tl010_pl000_tv010_pv000.png");
}

TEST_CASE("a write that fails half-way removes its temporary output and leaves no result") {
  const fs::path dir = test::scratch_dir("halfway");
  const MeasuredSample s = bonn_test_sample();
  WriteOptions cancel_after_first_batch{90, [](size_t done, size_t) {
                                          if (done > 0) throw CancelledError("stop");
                                        }};
  CHECK_THROWS_AS(write_sample(s, (dir / "s.zip").string(), cancel_after_first_batch), CancelledError);
  CHECK_THROWS_AS(write_sample(s, (dir / "s").string(), cancel_after_first_batch), CancelledError);
  CHECK(fs::is_empty(dir));
  // Loading is cancelled the same way.
  CHECK_THROWS_AS(load_sample(written_zip().string(), [](size_t, size_t) { throw CancelledError("stop"); }),
                  CancelledError);
}
