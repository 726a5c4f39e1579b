// `btfvq compress`: measured samples into a (new or existing) database, with progress per phase.
#include <filesystem>
#include <fstream>
#include <iostream>
#include <mutex>

#include "client/cli.h"
#include "client/progress_bar.h"
#include "pipeline/encode/compress.h"
#include "pipeline/format/database.h"
#include "pipeline/io/sample_io.h"

namespace btfvq::cli {
namespace {

namespace fs = std::filesystem;

int run_compress(const Args& a) {
  if (a.positional.empty()) throw InputError("usage: btfvq compress IN... --db OUT.btfdb [--config F]");
  const std::string out = a.require("db");
  if (a.has("name") && a.positional.size() != 1) throw InputError("--name needs exactly one input");
  CompressOptions options;
  if (auto file = a.get("config")) options.config.merge(ParameterDictionary::load_file(*file));
  validate_pipeline_config(options.config);  // a misspelled setting fails before any work

  Database db;
  if (fs::exists(out)) db = read_database(out);
  nlohmann::json reports = nlohmann::json::array();
  for (const auto& input : a.positional) {
    const std::string name = a.positional.size() == 1 ? a.get_or("name", material_name_of(input)) : material_name_of(input);
    if (db.find(name)) throw InputError("'" + out + "' already has a material named '" + name + "'");
    MeasuredSample sample;
    {
      ProgressBar bar("load " + name);
      sample = load_sample(input, [&](size_t done, size_t total) { bar.update(double(done) / double(total)); });
      bar.finish(std::to_string(sample.width()) + " x " + std::to_string(sample.height()) + ", " +
                 std::to_string(sample.pair_count()) + " images");
    }
    std::mutex m;
    std::unique_ptr<ProgressBar> bar;
    std::string stage;
    options.progress = [&](const CompressProgress& p) {
      std::lock_guard<std::mutex> lock(m);
      if (p.stage != stage) {
        if (bar) bar->finish();
        stage = p.stage;
        if (stage == "done") return;
        bar = std::make_unique<ProgressBar>(stage + " " + name);
      }
      if (bar)
        bar->update(p.texels_total ? double(p.texels_done) / double(p.texels_total) : 0.0,
                    std::to_string(p.texels_done) + "/" + std::to_string(p.texels_total) + " texels, P4 " +
                        std::to_string(p.sizes[CodebookId::P4]) + ", P1 " + std::to_string(p.sizes[CodebookId::P1]));
    };
    const CompressReport r = compress_material(db, sample, name, options);
    if (bar) bar->finish();
    reports.push_back(r.json);
  }
  // Round the new rows to what the file stores, so the in-memory model and the file decode alike.
  quantize_new_rows(db);
  write_database(db, out);
  const uint64_t bytes = fs::file_size(out);
  uint64_t raw = 0;
  for (const auto& mat : db.materials) raw += mat.raw_bytes;
  std::cout << "wrote " << out << ": " << db.materials.size() << " material(s), " << bytes << " bytes, ratio 1:"
            << (bytes ? double(raw) / double(bytes) : 0.0) << "\n";
  for (const auto& r : reports)
    for (const auto& p : r["phases"])
      std::cout << "  " << r["material"].get<std::string>() << " phase " << p["phase"] << ": " << p["texels"]
                << " texels, " << p["seconds"].get<double>() << " s, code-books " << p["codebook_sizes"].dump() << "\n";
  if (auto file = a.get("report")) {
    std::ofstream f(*file);
    f << nlohmann::json{{"database", out}, {"bytes", bytes}, {"raw_bytes", raw},
                        {"compression_ratio", bytes ? double(raw) / double(bytes) : 0.0}, {"materials", reports}}
             .dump(2);
    if (!f) throw InputError("cannot write the report '" + *file + "'");
  }
  return 0;
}

CommandRegistrar reg({"compress", "compress IN... --db OUT.btfdb [--config F] [--name N] [--report R.json]",
                      "compress measured samples (zip or directory) into a database; an existing database gains them",
                      {"db", "config", "name", "report"}, {}, run_compress});

}  // namespace
}  // namespace btfvq::cli
