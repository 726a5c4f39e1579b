// Rate-distortion of btfvq against the competitors users would pick instead (bench/baselines): per
// preset, btfvq at several qualities (`--quality`, docs/encoder.md "Quality") and every baseline at
// several sizes, all on the same sample in one run, evaluated with the same metrics; one table and
// one plot (ratio on a log axis against MSSIM) per preset, and btfvq's ratio over the best PCA
// baseline's at matched MSSIM. Samples are what users have: each is written as a UBO2003 JPEG zip
// (quality 95) and read back, and every method compresses and is scored against that.
//
// Each sample's results are kept in bench/results/rd/<sample>.json with the run that measured them
// (commit, date, arguments), and the section is assembled from every kept sample: the 256 x 256
// samples, an hour each here, can be measured by runs of their own without losing the others.
// While a sample runs, every scored point is also kept in bench/results/rd/<sample>.partial (with
// the commit and arguments): a run of the same clean commit and arguments that finds it (after a
// kill, or a session that ended) scores only the points still missing; the file goes when the
// sample's table is kept.
//
// Own options (kRdOptions below, `bench_rate_distortion --help`), also read from the environment
// variable BTFVQ_RD_ARGS so that `BTFVQ_RD_ARGS="--presets wood --size 64" make bench` reaches only
// this bench.
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <optional>
#include <sstream>

#include "bench/baselines/grouped_pca.h"
#include "bench/baselines/lab_pca.h"
#include "bench/baselines/per_view_pca.h"
#include "bench/baselines/texel_vq.h"
#include "bench/bench_common.h"
#include "pipeline/util/atomic_file.h"
#include "pipeline/io/btfbase.h"
#include "pipeline/encode/ceiling.h"
#include "pipeline/encode/compress.h"
#include "pipeline/encode/quality.h"
#include "pipeline/io/sample_io.h"
#include "pipeline/format/database.h"
#include "pipeline/metrics/btf_cielab.h"
#include "pipeline/metrics/metrics.h"
#include "pipeline/decode/reconstruct.h"
#include "pipeline/io/synthetic.h"

using namespace btfvq;
using baselines::BaselinePoint;

namespace {

const std::vector<Option> kRdOptions{
    {"presets", "a,b,..", "synthetic presets at --size, or none (tile,leather,wood,corduroy; --quick tile,leather,wood)"},
    {"size", "N", "their size (128; --quick 32)"},
    {"big", "p:N,..", "extra presets at their own size, or none (leather:256; --quick none)"},
    {"proposte", "N", "the real proposte sample cropped to N x N from its corner (256 = whole; --quick 16; 0 = skip)"},
    {"qualities", "a,b,..", "btfvq --quality values (20,35,50,65,80; --quick 30,50,70)"},
    {"phase2", "a,b,..", "more btfvq points at the default thresholds with schedule.phase2_fraction = a, b (none; "
                         "more growing texels raise quality where thresholds do not)"},
    {"pca", "a,b,..", "per-view PCA components (1,2,5; --quick 1,2)"},
    {"grouped", "a,b,..", "grouped PCA components (1,2,8; --quick 1,2)"},
    {"lab", "a,b,..", "CIELab PCA components (1,4,16,64; --quick 1,2,4,8)"},
    {"vq", "a,b,..", "texel VQ code-book entries (32,128; --quick 4)"},
    {"btf-cielab", "on|off", "the BTF-CIELab mean column (docs/metrics.md, default viewing condition; on)"}};

struct RdArgs {
  std::vector<std::string> presets{"tile", "leather", "wood", "corduroy"};
  int size = 128;
  std::vector<std::pair<std::string, int>> big{{"leather", 256}};
  int proposte = 256;
  std::vector<double> qualities{20, 35, 50, 65, 80};
  std::vector<double> phase2;
  std::vector<int> pca{1, 2, 5}, grouped{1, 2, 8}, lab{1, 4, 16, 64}, vq{32, 128};
  bool btf_cielab = true;
};

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  for (std::string item; std::getline(ss, item, sep);)
    if (!item.empty()) out.push_back(item);
  return out;
}

[[noreturn]] void usage(const std::string& what) {
  std::cerr << "bench_rate_distortion: " << what << "\n";
  std::exit(2);
}

int to_int(const std::string& s) {
  try {
    size_t used = 0;
    const int v = std::stoi(s, &used);
    if (used != s.size()) usage("not an integer: " + s);
    return v;
  } catch (const std::exception&) {
    usage("not an integer: " + s);
  }
}

std::vector<int> ints(const std::string& s) {
  std::vector<int> out;
  for (const auto& x : split(s, ',')) out.push_back(to_int(x));
  return out;
}

std::vector<std::string> environment_args() {
  const char* env = std::getenv("BTFVQ_RD_ARGS");
  return env ? split(env, ' ') : std::vector<std::string>{};
}

std::vector<std::pair<std::string, int>> big_samples(const std::string& list) {
  std::vector<std::pair<std::string, int>> big;
  if (list == "none") return big;
  for (const auto& item : split(list, ',')) {
    const auto colon = item.find(':');
    if (colon == std::string::npos) usage("--big wants preset:size, got " + item);
    big.emplace_back(item.substr(0, colon), to_int(item.substr(colon + 1)));
  }
  return big;
}

std::vector<double> doubles(const std::string& list) {
  std::vector<double> out;
  for (const auto& x : split(list, ',')) out.push_back(std::stod(x));
  return out;
}

RdArgs quick_defaults() {
  RdArgs r;
  r.size = 32;
  r.big.clear();
  r.proposte = 16;  // real data grows large code-books: even a 32 x 32 corner takes minutes per quality
  r.presets = {"tile", "leather", "wood"};
  r.pca = {1, 2};
  r.grouped = {1, 2};
  r.lab = {1, 2, 4, 8};
  r.vq = {4};
  r.qualities = {30, 50, 70};
  return r;
}

// The defaults (of --quick or not), then the options given.
RdArgs rd_args(const btfvq::Args& given, bool quick) {
  RdArgs r = quick ? quick_defaults() : RdArgs{};
  if (auto v = given.get("presets")) r.presets = *v == "none" ? std::vector<std::string>{} : split(*v, ',');
  if (auto v = given.get("size")) r.size = to_int(*v);
  if (auto v = given.get("big")) r.big = big_samples(*v);
  if (auto v = given.get("proposte")) r.proposte = to_int(*v);
  for (const auto& v : given.all("phase2")) {
    const auto more = doubles(v);
    r.phase2.insert(r.phase2.end(), more.begin(), more.end());
  }
  if (auto v = given.get("qualities")) r.qualities = doubles(*v);
  if (auto v = given.get("pca")) r.pca = ints(*v);
  if (auto v = given.get("grouped")) r.grouped = ints(*v);
  if (auto v = given.get("lab")) r.lab = ints(*v);
  if (auto v = given.get("vq")) r.vq = ints(*v);
  if (auto v = given.get("btf-cielab")) {
    if (*v != "on" && *v != "off") usage("--btf-cielab wants on or off, got " + *v);
    r.btf_cielab = *v == "on";
  }
  return r;
}

struct Point {
  std::string method, setting;
  double ratio = 0, seconds = 0;
  uint64_t bytes = 0;
  EvaluationReport e;
  std::optional<double> btf_cielab;  // its mean, when the column is on
  int size = 0;                      // a baseline's size parameter (its components or entries)
  std::map<std::string, uint64_t> levels;  // btfvq: bytes in the file per code-book, "P6" the material's indices
};

nlohmann::json to_json(const Point& p) {
  nlohmann::json j = {{"method", p.method}, {"setting", p.setting}, {"size", p.size}, {"ratio", p.ratio},
                      {"bytes", p.bytes}, {"seconds", p.seconds}, {"mssim_y", p.e.mssim_y}, {"mssim_cb", p.e.mssim_cb},
                      {"mssim_cr", p.e.mssim_cr}, {"ciede2000_mean", p.e.ciede2000_mean},
                      {"ciede2000_p95", p.e.ciede2000_p95}, {"images", p.e.images}};
  // JSON has no infinity: an identical decoding's PSNR is kept as null.
  j["psnr"] = std::isfinite(p.e.psnr) ? nlohmann::json(p.e.psnr) : nlohmann::json(nullptr);
  if (!p.levels.empty()) j["levels"] = p.levels;
  if (p.btf_cielab) j["btf_cielab"] = *p.btf_cielab;
  return j;
}

Point point_from_json(const nlohmann::json& j) {
  Point p;
  p.method = j.at("method");
  p.setting = j.at("setting");
  p.size = j.at("size");
  p.ratio = j.at("ratio");
  p.bytes = j.at("bytes");
  p.seconds = j.at("seconds");
  p.e.mssim_y = j.at("mssim_y");
  p.e.mssim_cb = j.at("mssim_cb");
  p.e.mssim_cr = j.at("mssim_cr");
  p.e.psnr = j.at("psnr").is_null() ? std::numeric_limits<double>::infinity() : j.at("psnr").get<double>();
  p.e.ciede2000_mean = j.at("ciede2000_mean");
  p.e.ciede2000_p95 = j.at("ciede2000_p95");
  p.e.images = j.at("images");
  if (j.contains("btf_cielab")) p.btf_cielab = j.at("btf_cielab").get<double>();
  if (j.contains("levels")) p.levels = j.at("levels").get<std::map<std::string, uint64_t>>();
  return p;
}

// The points of one sample scored so far, kept on disk after each one so that an interrupted run of
// the same clean commit and arguments picks them up instead of scoring them again.
class Journal {
 public:
  Journal(std::filesystem::path path, std::string run) : path_(std::move(path)), run_(std::move(run)) {
    // A dirty tree or an unknown commit may be other code than the points were scored with.
    resumable_ = run_.find("(dirty)") == std::string::npos && run_.rfind("unknown", 0) != 0;
    if (!resumable_ || !std::filesystem::exists(path_)) return;
    try {
      const auto j = nlohmann::json::parse(std::ifstream(path_));
      if (j.at("run") != run_) return;
      for (const auto& p : j.at("points")) points_.push_back(point_from_json(p));
    } catch (const std::exception& e) {
      std::fprintf(stderr, "  ignoring %s: %s\n", path_.string().c_str(), e.what());
      points_.clear();
    }
  }
  const Point* find(const std::string& method, const std::string& setting) const {
    for (const auto& p : points_)
      if (p.method == method && p.setting == setting) return &p;
    return nullptr;
  }
  const Point* find(const std::string& method, int size) const {
    for (const auto& p : points_)
      if (p.method == method && p.size == size) return &p;
    return nullptr;
  }
  void add(const Point& p) {
    points_.push_back(p);
    if (!resumable_) return;
    std::filesystem::create_directories(path_.parent_path());
    nlohmann::json j = {{"run", run_}, {"points", nlohmann::json::array()}};
    for (const auto& q : points_) j["points"].push_back(to_json(q));
    write_file_atomically(path_.string(), j.dump(1));
  }
  void finish() const { std::filesystem::remove(path_); }

 private:
  std::filesystem::path path_;
  std::string run_;
  bool resumable_ = false;
  std::vector<Point> points_;
};

// Every method's decoded sample is scored by the same calls: the metrics of eval, and BTF-CIELab at
// its default viewing condition when asked (a few minutes per point at 256 x 256).
void score(Point& p, const MeasuredSample& sample, const MeasuredSample& decoded, bool with_btf_cielab) {
  p.e = evaluate(sample, decoded);
  if (with_btf_cielab) p.btf_cielab = btf_cielab(sample, decoded).mean;
}

// The pipeline config of quality q and, if phase2 >= 0, that schedule.phase2_fraction.
ParameterDictionary btfvq_config(double quality, double phase2) {
  nlohmann::json overrides = nlohmann::json::object();
  if (phase2 >= 0) overrides["schedule"] = {{"phase2_fraction", phase2}};
  return pipeline_config(with_quality(quality, overrides), "rate-distortion bench");
}

std::string btfvq_setting(double quality, double phase2) {
  char s[64];
  if (phase2 >= 0) std::snprintf(s, sizeof s, "Q %.0f, phase2_fraction %.2g", quality, phase2);
  else std::snprintf(s, sizeof s, "Q %.0f", quality);
  return s;
}

Point run_btfvq(const MeasuredSample& sample, double quality, double phase2, bool with_btf_cielab,
                const std::filesystem::path& scratch) {
  bench::Stopwatch sw;
  Database db;
  CompressOptions options;
  options.config = btfvq_config(quality, phase2);
  compress_material(db, sample, "m", options);
  quantize_new_rows(db);
  const auto path = scratch / "rd.btfdb";
  write_database(db, path.string());
  Point p;
  p.seconds = sw.seconds();
  p.method = "btfvq";
  p.setting = btfvq_setting(quality, phase2);
  p.bytes = std::filesystem::file_size(path);
  const DatabaseInfo info = inspect_database(path.string());
  for (int i = 0; i < kCodebookCount; ++i) p.levels[codebook_name(CodebookId(i))] = info.codebook_bytes[i];
  for (const auto& m : info.materials) p.levels["P6"] += m.section_bytes;
  score(p, sample, reconstruct_sample(read_database(path.string()), "m", sample), with_btf_cielab);
  std::filesystem::remove(path);
  return p;
}

Point from_baseline(const MeasuredSample& sample, BaselinePoint& b, bool with_btf_cielab) {
  Point p;
  p.method = b.method;
  p.setting = b.setting;
  p.size = b.size;
  p.bytes = b.bytes;
  p.seconds = b.seconds;
  score(p, sample, b.decoded, with_btf_cielab);
  b.decoded = MeasuredSample();
  return p;
}

// A corner of a sample (the real data is 256 x 256; --quick compares on a crop of it).
MeasuredSample crop(const MeasuredSample& s, int size) {
  if (size >= s.width() && size >= s.height()) return s;
  const int w = std::min(size, s.width()), h = std::min(size, s.height());
  std::vector<std::vector<Direction>> lights;
  for (size_t v = 0; v < s.view_count(); ++v) lights.push_back(s.lights(v));
  MeasuredSample out(w, h, s.views(), lights, s.dynamic());
  const size_t n = s.pair_count() * 3;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      std::copy_n(s.ldr_data().data() + (size_t(y) * size_t(s.width()) + size_t(x)) * n, n,
                  out.ldr_data().data() + (size_t(y) * size_t(w) + size_t(x)) * n);
  return out;
}

// log(ratio) interpolated linearly in MSSIM along a curve; nullopt outside the curve's MSSIM range.
std::optional<double> ratio_at(std::vector<const Point*> curve, double mssim) {
  std::sort(curve.begin(), curve.end(), [](const Point* a, const Point* b) { return a->e.mssim_y < b->e.mssim_y; });
  if (curve.empty() || mssim < curve.front()->e.mssim_y || mssim > curve.back()->e.mssim_y) return std::nullopt;
  for (size_t i = 0; i + 1 < curve.size(); ++i) {
    const double m0 = curve[i]->e.mssim_y, m1 = curve[i + 1]->e.mssim_y;
    if (mssim >= m0 && mssim <= m1) {
      const double w = m1 > m0 ? (mssim - m0) / (m1 - m0) : 0.0;
      return std::exp((1 - w) * std::log(curve[i]->ratio) + w * std::log(curve[i + 1]->ratio));
    }
  }
  return curve.back()->ratio;  // a single point at exactly this MSSIM
}

bool is_pca(const std::string& method) { return method.find("PCA") != std::string::npos; }

struct Matched {
  std::string text;  // one markdown line
  nlohmann::json json;
  int below_2x = 0, bounded = 0;  // bounded: factors that are only upper bounds
};

// At each btfvq point's MSSIM: btfvq's ratio over the best PCA baseline's interpolated ratio. Where
// every PCA curve lies above that MSSIM, the ratio of the PCA curve's lowest-MSSIM point (a lower
// bound of what PCA reaches at the lower quality) gives an upper bound of the factor.
Matched matched_mssim(const std::vector<Point>& points, const std::function<bool(const std::string&)>& is_pca) {
  std::map<std::string, std::vector<const Point*>> curves;
  for (const auto& p : points) curves[p.method].push_back(&p);
  Matched out;
  out.json = nlohmann::json::array();
  std::ostringstream line;
  int at_least_2x = 0, compared = 0;
  for (const Point* b : curves["btfvq"]) {
    double best = 0;
    std::string best_method;
    bool bound = false;
    for (const auto& [method, curve] : curves) {
      if (!is_pca(method)) continue;
      if (auto r = ratio_at(curve, b->e.mssim_y); r && *r > best) best = *r, best_method = method;
    }
    if (best == 0) {  // outside every PCA curve
      for (const auto& [method, curve] : curves) {
        if (!is_pca(method)) continue;
        const Point* lowest = *std::min_element(curve.begin(), curve.end(), [](auto* x, auto* y) { return x->e.mssim_y < y->e.mssim_y; });
        if (lowest->e.mssim_y > b->e.mssim_y && lowest->ratio > best) best = lowest->ratio, best_method = method, bound = true;
      }
    }
    char buf[256];
    if (best == 0) {
      std::snprintf(buf, sizeof buf, "MSSIM %.3f: no PCA setting reaches it (btfvq 1:%.0f); ", b->e.mssim_y, b->ratio);
      out.json.push_back({{"mssim", b->e.mssim_y}, {"btfvq_ratio", b->ratio}, {"factor", nullptr}});
    } else {
      const double f = b->ratio / best;
      ++compared;
      out.bounded += bound;
      at_least_2x += f >= 2.0;
      std::snprintf(buf, sizeof buf, "MSSIM %.3f: btfvq 1:%.0f vs %s 1:%.0f%s = **%s%.2fx**; ", b->e.mssim_y, b->ratio,
                    best_method.c_str(), best, bound ? " (its lowest-MSSIM point, still above)" : "", bound ? "<= " : "", f);
      out.json.push_back({{"mssim", b->e.mssim_y}, {"btfvq_ratio", b->ratio}, {"pca", best_method}, {"pca_ratio", best},
                          {"factor", f}, {"upper_bound", bound}});
    }
    line << buf;
  }
  out.below_2x = compared - at_least_2x;
  std::string s = line.str();
  if (s.size() >= 2) s.resize(s.size() - 2);
  out.text = s + (compared ? (at_least_2x == compared ? (out.bounded ? " -- upper bounds only: 2x is not established."
                                                                        : " -- at least 2x at every matched point.")
                                                      : " -- below 2x at " + std::to_string(compared - at_least_2x) +
                                                            " of " + std::to_string(compared) + " matched points.")
                           : "");
  return out;
}

void write_plot(const bench::Args& args, const std::string& key, const std::string& title, const std::vector<Point>& points,
                double ceiling) {
  nlohmann::json curves = nlohmann::json::object();
  for (const auto& p : points)
    curves[p.method].push_back({{"ratio", p.ratio}, {"mssim", p.e.mssim_y}, {"setting", p.setting}});
  const auto json_path = args.scratch / ("rd_" + key + ".json");
  std::ofstream(json_path) << nlohmann::json{{"title", title}, {"curves", curves}, {"floor", ceiling}}.dump(1);
  const auto png = args.figures / ("rd_" + key + ".png");
  // Debian's python3-matplotlib belongs to /usr/bin/python3, which a user's pyenv may shadow.
  const std::string cmd = "$( [ -x /usr/bin/python3 ] && echo /usr/bin/python3 || echo python3 ) '" + std::string(BTFVQ_BENCH_DIR) + "/plot_rd.py' '" + json_path.string() + "' '" +
                          png.string() + "'";
  if (std::system(cmd.c_str()) != 0) std::cerr << "plot failed: " << cmd << "\n";
}


// "a, b and c" of a list already formatted.
std::string joined(const std::vector<std::string>& items) {
  std::string out;
  for (size_t i = 0; i < items.size(); ++i)
    out += (i == 0 ? "" : i + 1 == items.size() ? " and " : ", ") + items[i];
  return out;
}

std::string fixed(const char* format, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, format, v);
  return buf;
}

// Why btfvq stays below 2x the best PCA baseline on a sample: the paragraph BENCHMARKS.md prints
// next to its numbers, derived from the sample's kept figures only (so that a better rule also
// reaches samples measured before it): which PCA wins, what each side stores per texel at the points
// below 2x, how many times each side's size grows over them, and, where the run recorded it, which of
// btfvq's levels hold its bytes there. Empty when btfvq is at 2x everywhere it was matched.
std::string why_not_2x(const nlohmann::json& f) {
  struct Match {
    double mssim, ratio, pca_ratio;
  };
  std::vector<Match> measured, below;  // by MSSIM, as matched_mssim lists btfvq's points
  std::map<std::string, int> best;
  int bounded = 0;
  for (const auto& m : f.at("matched_mssim")) {
    if (!m.at("factor").is_number()) continue;
    ++best[m.at("pca").get<std::string>()];
    if (m.value("upper_bound", false)) {
      ++bounded;
      continue;
    }
    const Match x{m.at("mssim").get<double>(), m.at("btfvq_ratio").get<double>(), m.at("pca_ratio").get<double>()};
    measured.push_back(x);
    if (m.at("factor").get<double>() < 2.0) below.push_back(x);
  }
  if (below.empty() && bounded == 0) return "";
  const auto by_mssim = [](const Match& a, const Match& b) { return a.mssim < b.mssim; };
  std::sort(measured.begin(), measured.end(), by_mssim);
  std::sort(below.begin(), below.end(), by_mssim);
  std::string strongest;
  for (const auto& [method, n] : best)
    if (strongest.empty() || n > best[strongest]) strongest = method;

  std::ostringstream w;
  const auto text = [&w] {
    std::string t = w.str();
    while (!t.empty() && t.back() == ' ') t.pop_back();
    return t;
  };
  w << "Why not 2x everywhere here: the strongest PCA is " << strongest << ". ";
  if (strongest == "CIELab PCA")
    w << "A full-matrix factorization stores each eigen-ABRDF (6561 values) once for all texels and each eigen-image "
         "at one byte per texel, so a material whose texels mix a few reflectance behaviours is nearly low-rank and a "
         "handful of components reach btfvq's quality. ";
  else
    w << "Its per-view (or per-group) bases follow the light dependence closely at one byte per texel and component. ";
  if (bounded > 0)
    w << "Where even the PCA's smallest measured setting is above btfvq's MSSIM, only an upper bound of the factor is "
         "known (a PCA cannot go below one component). ";
  if (below.empty()) return text();

  // Bytes per texel = raw bytes per texel / ratio (the samples here are 8-bit: 6561 x 3 bytes).
  const double raw_per_texel = f.value("raw_bytes_per_texel", 6561.0 * 3.0);
  std::vector<std::string> at, ours, theirs;
  for (const auto& b : below) {
    at.push_back(fixed("%.3f", b.mssim));
    ours.push_back(fixed("%.0f", raw_per_texel / b.ratio));
    theirs.push_back(fixed("%.0f", raw_per_texel / b.pca_ratio));
  }
  w << "Below 2x at MSSIM " << joined(at) << ": there btfvq stores " << joined(ours)
    << " bytes per texel, the best PCA at the same MSSIM " << joined(theirs) << ". ";

  // From the matched point before the first one below 2x (if any) to the last one below 2x.
  const auto first = std::find_if(measured.begin(), measured.end(), [&](const Match& m) { return m.mssim >= below.front().mssim; });
  const Match& from = first == measured.begin() ? *first : *(first - 1);
  const Match& to = below.back();
  if (to.mssim > from.mssim) {
    const double ours_grows = from.ratio / to.ratio, theirs_grows = from.pca_ratio / to.pca_ratio;
    w << "From MSSIM " << fixed("%.3f", from.mssim) << " to " << fixed("%.3f", to.mssim) << " btfvq's size grows "
      << fixed("%.1f", ours_grows) << "-fold, the best PCA's " << fixed("%.1f", theirs_grows) << "-fold"
      << (ours_grows > theirs_grows ? ": btfvq buys MSSIM with bytes more slowly there. "
                                    : ": the gap is not in how fast the curves rise but already at the lower point. ");
  }

  // Where btfvq's bytes are at the highest point below 2x (runs that recorded the levels).
  for (const auto& row : f.at("points")) {
    if (row.at("method") != "btfvq" || row.at("ratio").get<double>() != to.ratio || !row.contains("levels")) continue;
    std::vector<std::pair<uint64_t, std::string>> levels;
    uint64_t total = 0, per_texel = 0;
    for (const auto& [name, bytes] : row.at("levels").items()) {
      levels.emplace_back(bytes.get<uint64_t>(), name);
      total += bytes.get<uint64_t>();
      if (name == "P4" || name == "P6") per_texel += bytes.get<uint64_t>();
    }
    if (total == 0) break;
    std::sort(levels.rbegin(), levels.rend());
    std::vector<std::string> shares;
    for (size_t i = 0; i < levels.size() && i < 3; ++i)
      shares.push_back(levels[i].second + " " + fixed("%.0f%%", 100.0 * double(levels[i].first) / double(total)));
    w << "At MSSIM " << fixed("%.3f", to.mssim) << " (" << row.at("setting").get<std::string>() << ") its largest levels are "
      << joined(shares) << " of the code-book and index bytes; the per-texel rows (P4 entries and P6 indices) are "
      << fixed("%.0f%%", 100.0 * double(per_texel) / double(total))
      << (2 * per_texel < total ? ", so most bytes are the lower code-books that the growing phases build at that "
                                  "quality's thresholds, not per-texel rows. "
                                : ", so most bytes are per-texel rows. ");
    break;
  }
  return text();
}

// The command that reproduces this run, as bench/run.sh describes it (BTFVQ_BENCH_COMMAND) plus this
// bench's own arguments.
std::string run_command() {
  const char* base = std::getenv("BTFVQ_BENCH_COMMAND");
  const char* rd = std::getenv("BTFVQ_RD_ARGS");
  std::string c = base ? base : "bench_rate_distortion";
  if (rd && *rd) c = "BTFVQ_RD_ARGS=\"" + std::string(rd) + "\" " + c;
  return c;
}

std::string utc_now() {
  const std::time_t t = std::time(nullptr);
  char buf[64];
  std::strftime(buf, sizeof buf, "%Y-%m-%d %H:%M UTC", std::gmtime(&t));
  return buf;
}

// --quick results (tiny samples) are kept apart so they never mix into the full-size section.
std::filesystem::path sample_store(const bench::Args& args, bool quick) {
  return args.figures / (quick ? "rd-quick" : "rd");
}

// Synthetic presets first by size, in the presets' own order, then the real data.
int sample_order(const std::string& key) {
  static const std::vector<std::string> presets = {"tile", "foil", "wood", "leather", "fabric", "corduroy", "wool"};
  const auto us = key.rfind('_');
  const std::string name = key.substr(0, us);
  const int size = us == std::string::npos ? 0 : std::atoi(key.c_str() + us + 1);
  const auto it = std::find(presets.begin(), presets.end(), name);
  return it == presets.end() ? 1000000 + size : size * 100 + int(it - presets.begin());
}

void keep_sample(const bench::Args& args, bool quick, const std::string& key, const std::string& title,
                 const std::string& markdown, const nlohmann::json& figures, const std::string& command) {
  const auto dir = sample_store(args, quick);
  std::filesystem::create_directories(dir);
  const char* commit = std::getenv("BTFVQ_BENCH_COMMIT");
  const nlohmann::json kept = {{"key", key}, {"title", title}, {"markdown", markdown},
                               {"figures", figures},
                               {"provenance", {{"commit", commit ? commit : "unknown"}, {"command", command}, {"date", utc_now()}}}};
  write_file_atomically((dir / (key + ".json")).string(), kept.dump(1));
}

// A kept sample's markdown with the why paragraph in front of its memory line. Samples kept before
// the paragraph was derived here carry an older one in their markdown: it is replaced.
std::string with_why(std::string markdown, const std::string& why) {
  const std::string old = "Why not 2x everywhere here:";
  if (const auto at = markdown.find(old); at != std::string::npos) {
    const auto end = markdown.find("\n\n", at);
    markdown.erase(at, end == std::string::npos ? std::string::npos : end + 2 - at);
  }
  if (why.empty()) return markdown;
  const auto memory = markdown.find("Peak resident memory");
  return markdown.insert(memory == std::string::npos ? markdown.size() : memory, why + "\n\n");
}

// The section: the method, then every kept sample with the run that measured it, then the tally.
void write_rd_section(const bench::Args& args, bool quick) {
  std::vector<nlohmann::json> kept;
  std::filesystem::create_directories(sample_store(args, quick));  // a run may measure no sample
  for (const auto& f : std::filesystem::directory_iterator(sample_store(args, quick)))
    if (f.path().extension() == ".json") kept.push_back(nlohmann::json::parse(std::ifstream(f.path())));
  std::sort(kept.begin(), kept.end(), [](const nlohmann::json& a, const nlohmann::json& b) {
    return sample_order(a["key"].get<std::string>()) < sample_order(b["key"].get<std::string>());
  });
  std::ostringstream md;
  md << "Each sample is written as a UBO2003 zip of JPEG images (quality 95), as real archives are, read back, "
        "and compressed by btfvq (`compress_material` at each `--quality` Q of docs/encoder.md, Q 50 = the shipped "
        "settings; ratio = raw bytes / .btfdb file bytes) and by four baselines built in bench/baselines "
        "with Eigen, each decoded at the 81 x 81 measured directions and evaluated with pipeline/metrics/metrics.h. Baseline "
        "bytes count every stored byte: factors and code-vectors 8-bit, each vector with its own float32 [min, max] "
        "range, VQ indices at ceil(log2 N) bits. Baselines: **per-view PCA** (a PCA per view over texels' 81 lights x "
        "RGB, C components, paper 000's \"PCA\" column uses C = 5); **grouped PCA** (seed 002: 3 neighbouring views "
        "per group, rows centred per texel, C components; the thesis uses C = 8); **CIELab PCA** (seed 003 Sec. 5.1: "
        "full-matrix PCA of the L, a, b channels over all 6561 pairs, k components in total picked greedily by sigma; "
        "no perceptual filter); **one-level VQ** (btfvq's resampled texels, one k-means code-book of N whole "
        "texels). Encode time of a baseline = its decomposition (shared by its sizes) plus the size's quantization. "
        "MSSIM on BT.601 luma; CIEDE2000 mean over every texel of every image; BTF-CIELab mean (docs/metrics.md, "
        "pipeline/metrics/btf_cielab.h) of the decoded sample against the sample at the default viewing condition "
        "(14.14 texels per degree, 100 degrees per second), in tables measured since it was added. Every table comes from one run of "
        "this bench on that sample (its command, commit and date are under its heading); the samples are kept in "
        "bench/results/rd/ so that the 256 x 256 ones (about an hour each here) can be measured by runs of their own.\n\n";
  if (quick) md << "*--quick: 32 x 32 samples and a 16 x 16 corner of proposte; every ratio depends on the texel "
                   "count (PCA bases of 243 to 6561 values and btfvq's code-books are shared by fewer texels), so quick "
                   "ratios are not full-size ratios; real data grows large code-books, so the small proposte corner "
                   "has a low btfvq ratio.*\n\n";
  nlohmann::json figures = nlohmann::json::object();
  int wins = 0, somewhere = 0;
  std::string won;
  for (const auto& k : kept) {
    // A matched point counts when measured (not an upper bound) at 2x or more.
    int points = 0, at_2x = 0;
    for (const auto& m : k["figures"]["matched_mssim"]) {
      if (!m["factor"].is_number()) continue;
      ++points;
      at_2x += m["factor"].get<double>() >= 2.0 && !m.value("upper_bound", false);
    }
    somewhere += at_2x > 0;
    const bool everywhere = points > 0 && at_2x == points;
    const auto& p = k["provenance"];
    md << "### " << k["title"].get<std::string>() << "\n\n*Measured by `" << p["command"].get<std::string>()
       << "` at commit " << p["commit"].get<std::string>() << " on " << p["date"].get<std::string>() << ".*\n\n"
       << with_why(k["markdown"].get<std::string>(), why_not_2x(k["figures"]));
    figures[k["key"].get<std::string>()] = k["figures"];
    if (everywhere) ++wins, won += (won.empty() ? "" : ", ") + k["title"].get<std::string>();
  }
  md << "btfvq's ratio is at least 2x the best PCA baseline's at every matched MSSIM on **" << wins << " of "
     << kept.size() << "** samples" << (won.empty() ? "" : " (" + won + ")") << "; at one or more of its matched MSSIM "
     << "values (not counting upper bounds) on **" << somewhere << " of " << kept.size() << "**.\n";
  figures["samples_at_least_2x"] = wins;
  figures["samples_at_least_2x_somewhere"] = somewhere;
  bench::write_section(args, "Rate-distortion against the baselines", 35, md.str(), figures, /*own_provenance=*/true);
}

}  // namespace

int main(int argc, char** argv) {
  const auto args = bench::parse_args(argc, argv, kRdOptions, "The environment variable BTFVQ_RD_ARGS holds more of these, read after the command line.", environment_args());
  const bool quick = args.quick;
  const RdArgs rd = rd_args(args.given, quick);

  std::vector<std::pair<std::string, int>> synth;
  for (const auto& p : rd.presets) synth.emplace_back(p, rd.size);
  synth.insert(synth.end(), rd.big.begin(), rd.big.end());

  const std::string rd_command = run_command();
  auto run_case = [&](const std::string& key, const std::string& title, const MeasuredSample& measured) {
    std::fprintf(stderr, "== %s\n", title.c_str());
    // As users have it: JPEG images in a zip, read back (what every method below compresses and is
    // scored against).
    const auto zip = args.scratch / ("rd-" + key + ".zip");
    write_sample(measured, zip.string());
    const MeasuredSample sample = load_sample(zip.string());
    std::filesystem::remove(zip);
    const bench::Stopwatch clock;
    std::vector<Point> points;
    const char* commit = std::getenv("BTFVQ_BENCH_COMMIT");
    Journal journal(sample_store(args, quick) / (key + ".partial"),
                    std::string(commit ? commit : "unknown") + (rd.btf_cielab ? ", btf-cielab" : ""));
    const double raw = double(sample.raw_bytes());
    auto report = [&](const Point& p, bool resumed) {
      if (resumed) std::fprintf(stderr, "  %s %s: 1:%.0f MSSIM %.3f (kept by an interrupted run of this commit)\n",
                                p.method.c_str(), p.setting.c_str(), p.ratio, p.e.mssim_y);
      else std::fprintf(stderr, "  %s %s: 1:%.0f MSSIM %.3f (encode %.1f s, %.0f s so far)\n", p.method.c_str(),
                        p.setting.c_str(), p.ratio, p.e.mssim_y, p.seconds, clock.seconds());
    };
    std::vector<std::pair<double, double>> settings;  // (quality, phase2_fraction or -1)
    for (double q : rd.qualities) settings.emplace_back(q, -1.0);
    for (double f : rd.phase2) settings.emplace_back(kDefaultQuality, f);
    for (const auto& [s, f] : settings) {
      if (const Point* kept = journal.find("btfvq", btfvq_setting(s, f))) {
        points.push_back(*kept);
        report(*kept, true);
        continue;
      }
      points.push_back(run_btfvq(sample, s, f, rd.btf_cielab, args.scratch));
      points.back().ratio = raw / double(points.back().bytes);
      journal.add(points.back());
      report(points.back(), false);
    }
    // A baseline runs only for the sizes not kept; its points keep the order of the sizes asked.
    auto baseline = [&](const std::string& method, const std::vector<int>& sizes,
                        const std::function<void(const std::vector<int>&, const baselines::PointSink&)>& run) {
      std::vector<int> missing;
      for (int n : sizes)
        if (!journal.find(method, n)) missing.push_back(n);
      if (!missing.empty())
        run(missing, [&](BaselinePoint& b) {
          Point p = from_baseline(sample, b, rd.btf_cielab);
          p.ratio = raw / double(p.bytes);
          journal.add(p);
          report(p, false);
        });
      for (int n : sizes) {
        const Point* p = journal.find(method, n);
        if (!p) throw std::runtime_error(method + " gave no point of size " + std::to_string(n));
        if (std::find(missing.begin(), missing.end(), n) == missing.end()) report(*p, true);
        points.push_back(*p);
      }
    };
    baseline("per-view PCA", rd.pca, [&](const auto& sizes, const auto& sink) { baselines::per_view_pca(sample, sizes, sink); });
    baseline("grouped PCA (k=3)", rd.grouped, [&](const auto& sizes, const auto& sink) { baselines::grouped_pca(sample, 3, sizes, sink); });
    baseline("CIELab PCA", rd.lab, [&](const auto& sizes, const auto& sink) { baselines::lab_pca(sample, sizes, sink); });
    baseline("one-level VQ", rd.vq, [&](const auto& sizes, const auto& sink) {
      baselines::texel_vq(sample, ParameterDictionary::embedded_default("pipeline"), sizes, sink);
    });

    std::ostringstream md;
    const bool cielab = rd.btf_cielab;
    md << "| method | setting | ratio | bytes | MSSIM (Y) | PSNR dB | CIEDE2000 mean | " << (cielab ? "BTF-CIELab mean | " : "")
       << "encode s |\n"
       << "|---|---|---|---|---|---|---|" << (cielab ? "---|" : "") << "---|\n";
    nlohmann::json rows = nlohmann::json::array();
    for (const auto& p : points) {
      char row[512], perceptual[32] = "";
      if (p.btf_cielab) std::snprintf(perceptual, sizeof perceptual, " %.2f |", *p.btf_cielab);
      std::snprintf(row, sizeof row, "| %s | %s | 1:%.0f | %llu | %.3f | %.1f | %.2f |%s %.1f |\n", p.method.c_str(),
                    p.setting.c_str(), p.ratio, (unsigned long long)p.bytes, p.e.mssim_y, p.e.psnr, p.e.ciede2000_mean,
                    perceptual, p.seconds);
      md << row;
      rows.push_back({{"method", p.method}, {"setting", p.setting}, {"ratio", p.ratio}, {"bytes", p.bytes},
                      {"mssim", p.e.mssim_y}, {"psnr", p.e.psnr}, {"ciede2000_mean", p.e.ciede2000_mean}, {"seconds", p.seconds}});
      if (p.btf_cielab) rows.back()["btf_cielab_mean"] = *p.btf_cielab;
      if (!p.levels.empty()) rows.back()["levels"] = p.levels;
    }
    const Matched m = matched_mssim(points, is_pca);
    const Matched per_view = matched_mssim(points, [](const std::string& method) { return method == "per-view PCA"; });
    const EvaluationReport ceiling =
        evaluate(sample, parametrization_roundtrip(sample, ParameterDictionary::embedded_default("pipeline")));
    write_plot(args, key, title, points, ceiling.mssim_y);
    double lo = 1, hi = 0;
    for (const auto& p : points)
      if (p.method == "btfvq") lo = std::min(lo, p.e.mssim_y), hi = std::max(hi, p.e.mssim_y);
    char ceil_text[512];
    std::snprintf(ceil_text, sizeof ceil_text,
                  "Parametrization ceiling (every texel resampled to the grid and decoded back, no quantization): "
                  "MSSIM %.3f, PSNR %.1f dB, CIEDE2000 %.2f. btfvq's MSSIM spans %.3f-%.3f over the qualities.",
                  ceiling.mssim_y, ceiling.psnr, ceiling.ciede2000_mean, lo, hi);
    md << "\n" << ceil_text << "\n\nMatched MSSIM (btfvq / best PCA baseline, log-ratio interpolated along each curve): "
       << m.text << "\n\nAgainst per-view PCA alone (the \"PCA\" column of paper 000): " << per_view.text << "\n\n";
    md << "Peak resident memory of the run so far: " << int(bench::peak_rss_mb()) << " MB.\n\n";
    md << "![rate-distortion, " << title << "](bench/results/rd_" << key << ".png)\n\n";
    const nlohmann::json figures = {{"points", rows}, {"matched_mssim", m.json}, {"matched_mssim_per_view_pca", per_view.json},
                                    {"ceiling_mssim", ceiling.mssim_y}, {"below_2x", m.below_2x},
                                    {"raw_bytes_per_texel", raw / double(size_t(sample.width()) * size_t(sample.height()))},
                                    {"peak_memory_mb", bench::peak_rss_mb()}};
    keep_sample(args, quick, key, title, md.str(), figures, rd_command);
    journal.finish();
  };

  for (const auto& [preset, size] : synth) {
    SynthOptions o;
    o.preset = preset;
    o.size = size;
    o.seed = 1;
    o.dynamic = Dynamic::LDR;
    const std::string key = preset + "_" + std::to_string(size);
    run_case(key, preset + " " + std::to_string(size) + " x " + std::to_string(size), synthesize(o));
  }
  if (rd.proposte > 0) {
    const Database db = import_btfbase((args.testdata / "btfbase" / "proposte").string());
    const std::string name = db.materials.at(0).name;
    MeasuredSample sample = crop(reconstruct_bonn(db, name), rd.proposte);
    const std::string key = "proposte_" + std::to_string(sample.width());
    run_case(key,
             "proposte " + std::to_string(sample.width()) + " x " + std::to_string(sample.height()) +
                 " (the original database decoded at the measured directions" +
                 (rd.proposte < 256 ? ", top-left corner)" : ")"),
             sample);
  }
  write_rd_section(args, quick);
  return 0;
}
