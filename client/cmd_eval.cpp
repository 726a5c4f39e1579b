// `btfvq eval`: a material decoded at the reference's measured directions, compared with it.
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>

#include "client/cli.h"
#include "pipeline/format/database.h"
#include "pipeline/metrics/btf_cielab.h"
#include "pipeline/metrics/metrics.h"
#include "pipeline/decode/reconstruct.h"
#include "pipeline/io/sample_io.h"

namespace btfvq::cli {
namespace {

// JSON has no infinity: identical images give a PSNR of null there and "inf" in the text output.
nlohmann::json finite_or_null(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); }

// --metric btf-cielab[:RESOLUTION,SPEED]: the viewing condition, or nothing when not asked for.
std::optional<ViewingCondition> btf_cielab_condition(const Args& a) {
  const auto m = a.get("metric");
  if (!m) return std::nullopt;
  const std::string name = "btf-cielab";
  if (m->rfind(name, 0) != 0 || (m->size() > name.size() && (*m)[name.size()] != ':'))
    throw InputError("--metric '" + *m + "': the only extra metric is btf-cielab[:RESOLUTION,SPEED]");
  return m->size() > name.size() ? parse_viewing_condition(m->substr(name.size() + 1)) : ViewingCondition{};
}

int run_eval(const Args& a) {
  if (a.positional.size() != 1)
    throw InputError("usage: btfvq eval DB [--material NAME] --reference IN [--metric btf-cielab[:RESOLUTION,SPEED]] [--json FILE]");
  const std::optional<ViewingCondition> condition = btf_cielab_condition(a);
  const std::string path = a.positional[0];
  const Database db = read_database(path);
  if (db.materials.empty()) throw InputError(path + " holds no material");
  std::string name = a.get_or("material", "");
  if (name.empty()) {
    if (db.materials.size() != 1) throw InputError(path + " holds several materials: choose one with --material");
    name = db.materials[0].name;
  }
  const Material* mat = db.find(name);
  if (!mat) throw NotFoundError("no material '" + name + "' in " + path);
  const MeasuredSample reference = load_sample(a.require("reference"));
  if (reference.width() != mat->width || reference.height() != mat->height)
    throw InputError("the reference is " + std::to_string(reference.width()) + " x " + std::to_string(reference.height()) +
                     " but material '" + name + "' is " + std::to_string(mat->width) + " x " + std::to_string(mat->height));
  const MeasuredSample decoded = reconstruct_sample(db, name, reference);
  const EvaluationReport r = evaluate(reference, decoded);
  std::optional<BtfCielabReport> perceptual;
  if (condition) perceptual = btf_cielab(reference, decoded, {.condition = *condition});
  const uint64_t bytes = std::filesystem::file_size(path);
  uint64_t raw = 0;
  for (const auto& m : db.materials) raw += m.raw_bytes;
  // The ratio of the whole database: with several materials they share the code-books.
  const double ratio = double(raw) / double(bytes);
  std::cout << "material:          " << name << " (" << mat->width << " x " << mat->height << ", " << r.images
            << " direction pairs)\n"
            << "compression ratio: 1:" << ratio << " (" << raw << " raw bytes / " << bytes << " database bytes)\n"
            << "MSSIM (Y):         " << r.mssim_y << "   (Cb " << r.mssim_cb << ", Cr " << r.mssim_cr << ")\n"
            << "PSNR:              " << r.psnr << " dB\n"
            << "CIEDE2000:         mean " << r.ciede2000_mean << ", 95th percentile " << r.ciede2000_p95 << "\n";
  if (perceptual)
    std::cout << "BTF-CIELab:        mean " << perceptual->mean << ", std " << perceptual->stddev << ", RMS "
              << perceptual->rms << "   (" << perceptual->condition.resolution << " texels/degree, "
              << perceptual->condition.speed << " degrees/s; " << perceptual->seconds << " s)\n";
  if (auto file = a.get("json")) {
    std::ofstream f(*file);
    nlohmann::json j{{"material", name},
                        {"database_bytes", bytes},
                        {"raw_bytes", raw},
                        {"compression_ratio", ratio},
                        {"mssim", r.mssim_y},
                        {"mssim_cb", r.mssim_cb},
                        {"mssim_cr", r.mssim_cr},
                        {"psnr", finite_or_null(r.psnr)},
                        {"ciede2000_mean", r.ciede2000_mean},
                        {"ciede2000_p95", r.ciede2000_p95},
                        {"images", r.images}};
    if (perceptual)
      j["btf_cielab"] = {{"mean", perceptual->mean},
                         {"stddev", perceptual->stddev},
                         {"rms", perceptual->rms},
                         {"resolution", perceptual->condition.resolution},
                         {"speed", perceptual->condition.speed},
                         {"seconds", perceptual->seconds},
                         {"light_blocks", perceptual->light_blocks},
                         {"working_bytes", perceptual->working_bytes}};
    f << j.dump(2) << "\n";
    if (!f) throw InputError("cannot write '" + *file + "'");
  }
  return 0;
}

CommandRegistrar reg({"eval", "eval DB [--material NAME] --reference IN [--metric btf-cielab[:RESOLUTION,SPEED]] [--json FILE]",
                      "decode a material at the reference's directions and print ratio, MSSIM, PSNR, CIEDE2000",
                      {{"material", "NAME", "the material (needed when the database holds several)"},
                       {"reference", "IN", "the measured sample to compare with (zip or folder)"},
                       {"metric", "btf-cielab[:R,S]",
                        "also BTF-CIELab (docs/metrics.md) at R texels per degree and S degrees per second "
                        "(defaults 14.14, 100)"},
                       {"json", "FILE", "also write the metrics to FILE as JSON"}},
                      {}, run_eval});

}  // namespace
}  // namespace btfvq::cli
