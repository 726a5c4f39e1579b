// `btfvq compress`: measured samples into a (new or existing) database, with a progress bar per
// stage. Flags become options for one compress_database() call; this file only draws its progress.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <mutex>
#include <sstream>

#include "client/cli.h"
#include "client/progress_bar.h"
#include "pipeline/encode/checkpoint.h"
#include "pipeline/encode/compress.h"
#include "pipeline/encode/quality.h"
#include "pipeline/encode/target.h"
#include "pipeline/io/sample_io.h"

namespace btfvq::cli {
namespace {


// --quality sets every threshold by one rule; a --config file's settings win over it, key by key.
ParameterDictionary config_of(const Args& a) {
  const auto file = a.get("config");
  const nlohmann::json overrides = file ? ParameterDictionary::load_file(*file).json() : nlohmann::json();
  const std::string origin = file ? *file : std::string("--quality");
  if (auto q = a.get("quality")) return pipeline_config(with_quality(parse_number(*q, "--quality", 0, 100), overrides), origin);
  return pipeline_config(overrides, origin);
}

// A sample file or folder as the checkpoints' fingerprint sees it: where it is, how big, how new.
std::string identity_of(const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path p = fs::absolute(path, ec);
  uintmax_t bytes = 0;
  fs::file_time_type newest{};
  auto add = [&](const fs::directory_entry& e) {
    if (!e.is_regular_file(ec)) return;
    bytes += e.file_size(ec);
    newest = std::max(newest, e.last_write_time(ec));
  };
  if (fs::is_directory(p, ec))
    for (const auto& e : fs::recursive_directory_iterator(p, ec)) add(e);
  else
    add(fs::directory_entry(p, ec));
  return p.string() + " " + std::to_string(bytes) + " " + std::to_string(newest.time_since_epoch().count());
}

std::vector<MaterialInput> inputs_of(const Args& a) {
  std::vector<MaterialInput> inputs;
  for (const auto& path : a.positional) {
    const std::string name = a.positional.size() == 1 ? a.get_or("name", material_name_of(path)) : material_name_of(path);
    inputs.push_back({name, "load", [path](const ProgressFn& progress) { return load_sample(path, progress); },
                      identity_of(path)});
  }
  return inputs;
}

// One bar per (material, stage); the bar of a finished stage is closed when the next one starts.
class StageBars {
 public:
  void operator()(const CompressProgress& p) {
    std::lock_guard<std::mutex> lock(m_);
    const std::string key = p.stage + " " + p.material;
    if (key != key_) {
      if (bar_) bar_->finish();
      bar_.reset();
      key_ = key;
      if (p.stage == "done") return;
      bar_ = std::make_unique<ProgressBar>(p.material.empty() ? p.stage : key);
    }
    if (!bar_) return;
    const double f = p.texels_total ? double(p.texels_done) / double(p.texels_total) : 0.0;
    const std::string sizes = ", P4 " + std::to_string(p.sizes[CodebookId::P4]) + ", P1 " + std::to_string(p.sizes[CodebookId::P1]);
    const std::string unit = p.stage == "load" ? " images" : (p.stage == "refine" ? " iterations" : " texels") + sizes;
    bar_->update(f, std::to_string(p.texels_done) + "/" + std::to_string(p.texels_total) + unit);
  }
  void finish() {
    if (bar_) bar_->finish();
    bar_.reset();
  }

 private:
  std::mutex m_;
  std::string key_;
  std::unique_ptr<ProgressBar> bar_;
};

void print_summary(const std::string& out, const DatabaseSummary& s) {
  std::cout << "wrote " << out << ": " << s.materials << " material(s), " << s.bytes << " bytes, ratio 1:" << s.ratio
            << "\n";
  for (const auto& r : s.added) {
    if (r.json.contains("target")) {
      const auto& t = r.json["target"];
      const std::string metric = t["metric"];
      std::cout << "  " << r.material << ": target " << (metric == "mssim" ? "MSSIM " : "BTF-CIELab mean ")
                << t[metric].get<double>() << ", achieved " << t["achieved"].get<double>()
                << (t["reached"].get<bool>() ? "" : " (not reached)");
      if (t.contains("ceiling") && t["aimed"] != t[metric])
        std::cout << " (above the parametrization's ceiling " << t["ceiling"].get<double>() << ": aimed at "
                  << t["aimed"].get<double>() << ")";
      if (t.contains("finer_grid"))
        std::cout << " on the finer grid of " << t["finer_grid"]["n_phi_v"] << " view azimuths (the configured grid's ceiling "
                  << t["finer_grid"]["configured_ceiling"].get<double>() << ")";
      std::cout << " at quality " << t["quality"].get<double>()
                << ", ratio 1:" << t["ratio"].get<double>() << ", after " << t["attempts"].size() << " compression(s)\n";
    }
    if (r.json.contains("resumed")) std::cout << "  " << r.material << ": " << r.json["resumed"].get<std::string>() << "\n";
    for (const auto& p : r.json.value("phases", nlohmann::json::array()))
      std::cout << "  " << r.material << " phase " << p["phase"] << ": " << p["texels"] << " texels, "
                << p["seconds"].get<double>() << " s (CPU " << p.value("cpu_seconds", 0.0) << " s), code-books " << p["codebook_sizes"].dump() << "\n";
  }
}

void write_report(const std::string& file, const std::string& out, const DatabaseSummary& s) {
  nlohmann::json materials = nlohmann::json::array();
  for (const auto& r : s.added) materials.push_back(r.json);
  std::ofstream f(file);
  f << nlohmann::json{{"database", out}, {"bytes", s.bytes}, {"raw_bytes", s.raw_bytes},
                      {"compression_ratio", s.ratio}, {"write_seconds", s.write_seconds}, {"materials", materials}}
           .dump(2);
  if (!f) throw InputError("cannot write the report '" + file + "'");
}

int run_compress(const Args& a) {
  if (a.positional.empty()) throw InputError("usage: btfvq compress IN... --db OUT.btfdb [--config F]");
  const std::string out = a.require("db");
  if (a.has("name") && a.positional.size() != 1) throw InputError("--name needs exactly one input");
  if (int(a.has("quality")) + int(a.has("target-mssim")) + int(a.has("target-btf-cielab")) > 1)
    throw InputError("--quality, --target-mssim and --target-btf-cielab exclude each other");
  CompressOptions options;
  options.config = config_of(a);  // a misspelled setting fails before any work
  const auto mssim = a.get("target-mssim"), cielab = a.get("target-btf-cielab");
  if (mssim || cielab) {
    QualityTarget target;
    if (mssim) {
      target.value = *mssim == "default" ? kDefaultTargetMssim : parse_number(*mssim, "--target-mssim", 0.01, 0.999);
    } else {
      target.metric = TargetMetric::BtfCielab;
      target.value = parse_number(*cielab, "--target-btf-cielab", kMinTargetBtfCielab, kMaxTargetBtfCielab);
    }
    if (auto file = a.get("config")) target.overrides = ParameterDictionary::load_file(*file).json();
    options.target = target;
  }
  if (auto dir = a.get("resume")) {
    if (options.target) throw InputError("--resume and a target exclude each other (a target compresses several times)");
    options.checkpoint_folder = *dir;
  }
  StageBars bars;
  std::atomic<bool> said{false};
  std::mutex said_attempt;  // progress comes from worker threads
  std::string attempt;      // the last one said
  options.progress = [&](const CompressProgress& p) {
    if (p.resumed_tile >= 0 && !said.exchange(true)) {
      std::cerr << "\nresuming " << p.material << " from its checkpoint: " << p.resumed_tile << " phase-3 tile(s) done\n";
    }
    if (!p.attempt.empty()) {
      std::lock_guard lock(said_attempt);
      if (p.attempt != attempt) std::cerr << "\n" << p.material << ": target search, " << (attempt = p.attempt) << "\n";
    }
    bars(p);
  };
  const DatabaseSummary summary = compress_database(out, inputs_of(a), out, options);
  bars.finish();
  remove_checkpoints(options.checkpoint_folder);
  print_summary(out, summary);
  if (auto file = a.get("report")) write_report(*file, out, summary);
  return 0;
}

CommandRegistrar reg({"compress", "compress IN... --db OUT.btfdb [--quality Q | --target-mssim X | --target-btf-cielab X] [--config F] [--name N] [--report R.json] [--resume DIR]",
                      "compress measured samples (zip or directory) into a database; an existing database gains them",
                      {{"db", "OUT.btfdb", "the database to write (an existing one gains the materials)"},
                       {"quality", "Q", "0..100: every threshold by one rule (default 50, the shipped settings)"},
                       {"target-mssim", "X", "search the quality whose MSSIM (Y, whole sample) reaches X, or 'default' (0.90)"},
                       {"target-btf-cielab", "X",
                        "search the quality whose BTF-CIELab mean (docs/metrics.md, default viewing condition) is at most X"},
                       {"config", "F", "a configs/pipeline.json fragment; its settings win over --quality"},
                       {"name", "N", "the material's name (one input only; default: from the file name)"},
                       {"report", "R.json", "also write the compress report (counters, seconds) as JSON"},
                       {"resume", "DIR", "work folder for checkpoints: a killed run given the same folder continues from its last phase-3 tile"}},
                      {}, run_compress});

}  // namespace
}  // namespace btfvq::cli
