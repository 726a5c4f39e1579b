// `btfvq submit`: sends materials to a server as one job and prints the job id. Local files are
// uploaded first, in resumable pieces (PUT /v1/uploads/s<sha256 prefix> with Content-Range; the
// server checks the whole file's sha256).
#include <filesystem>
#include <fstream>
#include <iostream>

#include "client/cli.h"
#include "client/http_client.h"
#include "client/progress_bar.h"
#include "pipeline/encode/target.h"
#include <btfvq/error.h>
#include "pipeline/util/sha256.h"

namespace btfvq::cli {
namespace {
using nlohmann::json;

// Named after the content, so that the same command run again after an interruption finds the
// upload where it was cut off (and a file already uploaded is not sent again).
std::string upload_id_of(const std::string& sha256) { return "s" + sha256.substr(0, 32); }

json synthetic_source(const std::string& spec, int64_t seed) {
  const auto colon = spec.find(':');
  const std::string preset = spec.substr(0, colon);
  int size = 64;
  if (colon != std::string::npos) {
    const std::string s = spec.substr(colon + 1);
    size_t used = 0;
    try {
      size = std::stoi(s, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used == 0 || used != s.size()) throw InputError("--synthetic " + spec + ": SIZE must be an integer");
  }
  if (preset.empty()) throw InputError("--synthetic needs PRESET[:SIZE]");
  return {{"synthetic", {{"preset", preset}, {"size", size}, {"seed", seed}}}};
}

int run_submit(const Args& args) {
  HttpClient client(remote_from(args));
  const std::string database = args.require("db");
  const int64_t seed = args.integer("seed", 1, 0, 2147483647);

  // A material is named after its input file unless --name says otherwise (synthetic ones by the
  // server, after their preset).
  json sources = json::array();
  std::vector<std::string> default_names;
  for (const auto& s : args.all("synthetic")) {
    sources.push_back(synthetic_source(s, seed));
    default_names.emplace_back();
  }
  for (const auto& p : args.all("path")) {
    sources.push_back({{"path", p}});
    default_names.push_back(material_name_of(p));
  }
  std::vector<std::string> uploads = args.all("upload");
  for (const auto& file : uploads)
    if (!std::filesystem::exists(file)) throw InputError("--upload: '" + file + "' does not exist");
  if (sources.empty() && uploads.empty()) throw InputError("nothing to submit: give --synthetic, --upload or --path");

  json pipeline = json::object();
  if (auto config = args.get("config")) {
    std::ifstream in(*config);
    if (!in) throw InputError("--config: cannot read '" + *config + "'");
    try {
      pipeline = json::parse(in);
    } catch (const json::exception& e) {
      throw InputError("--config '" + *config + "': " + e.what());
    }
  }

  // Uploads go first so that a failed upload submits nothing.
  for (const auto& file : uploads) {
    const std::string sha = sha256_file(file);
    const std::string id = upload_id_of(sha);
    ProgressBar bar("upload " + std::filesystem::path(file).filename().string());
    const UploadResult up =
        client.upload_file(id, file, sha, [&](uint64_t done, uint64_t total) { bar.update_bytes(done, total); });
    std::string how = " uploaded as " + id;
    if (up.existed) how = " already on the server as " + id;
    else if (up.resumed_from > 0) how += " (resumed at " + ProgressBar::format_bytes(up.resumed_from) + ")";
    bar.finish(ProgressBar::format_bytes(up.record.value("size", uint64_t(0))) + how);
    sources.push_back({{"upload", id}});
    default_names.push_back(material_name_of(file));
  }

  const auto& names = args.all("name");
  if (!names.empty() && names.size() != sources.size())
    throw InputError("--name given " + std::to_string(names.size()) + " times for " + std::to_string(sources.size()) +
                     " materials (give one per material, in the order --synthetic, --path, --upload)");
  json materials = json::array();
  for (size_t i = 0; i < sources.size(); ++i) {
    json m = {{"source", sources[i]}};
    if (!names.empty()) m["name"] = names[i];
    else if (!default_names[i].empty()) m["name"] = default_names[i];
    materials.push_back(m);
  }
  json request = {{"database", database}, {"materials", materials}};
  if (!pipeline.empty()) request["pipeline"] = pipeline;
  if (auto q = args.get("quality")) request["quality"] = parse_number(*q, "--quality", 0, 100);
  if (auto t = args.get("target-mssim")) request["target_mssim"] = parse_number(*t, "--target-mssim", 0.01, 0.999);
  if (auto t = args.get("target-btf-cielab"))
    request["target_btf_cielab"] = parse_number(*t, "--target-btf-cielab", kMinTargetBtfCielab, kMaxTargetBtfCielab);
  if (auto c = args.get("btf-cielab")) request["btf_cielab"] = *c;  // the server checks it
  const json job = client.post_json("/v1/jobs", request);
  std::cout << job.at("id").get<std::string>() << "\n";
  return 0;
}

CommandRegistrar reg({"submit",
                      "submit --server URL --db NAME (--synthetic PRESET[:SIZE] | --upload PATH | --path SERVER_PATH)... "
                      "[--name NAME]... [--seed S] [--quality Q | --target-mssim X | --target-btf-cielab X] [--btf-cielab default|R,S] "
                      "[--config overrides.json]",
                      "submit materials to a btfvq server as one job; prints the job id",
                      remote_options({{"db", "NAME", "the database on the server that gains the materials"},
                                      {"synthetic", "PRESET[:SIZE]", "a synthetic material rendered by the server (size 64)"},
                                      {"upload", "PATH", "a local sample (.zip), uploaded first"},
                                      {"path", "SERVER_PATH", "a sample on the server, below its input root"},
                                      {"name", "NAME", "a material's name, once per material in the order --synthetic, --path, --upload"},
                                      {"seed", "S", "the seed of the synthetic materials (default 1)"},
                                      {"quality", "Q", "0..100: every threshold by one rule (the job field \"quality\")"},
                                      {"target-mssim", "X", "the MSSIM the job's materials must reach (the job field \"target_mssim\")"},
                                      {"target-btf-cielab", "X",
                                       "the BTF-CIELab mean the job's materials must not exceed (the job field \"target_btf_cielab\")"},
                                      {"btf-cielab", "default|R,S",
                                       "report each material's BTF-CIELab at that viewing condition (the job field \"btf_cielab\")"},
                                      {"config", "FILE", "pipeline settings (JSON) over configs/pipeline.json"}}),
                      {},
                      run_submit});

}  // namespace
}  // namespace btfvq::cli
