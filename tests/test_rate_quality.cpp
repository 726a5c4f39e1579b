// Rate-quality direction of the thresholds, end to end: synthesize -> compress_material ->
// quantize/serialize -> reconstruct_sample -> evaluate. More demanding thresholds must give a
// better reconstruction (MSSIM of Y) and a larger database (lower compression ratio).
#include <doctest/doctest.h>

#include <string>

#include "pipeline/encode/compress.h"
#include "pipeline/util/config.h"
#include "pipeline/format/database.h"
#include "pipeline/metrics/metrics.h"
#include "pipeline/decode/reconstruct.h"
#include "pipeline/io/synthetic.h"

using namespace btfvq;

namespace {

struct RateQuality {
  double ratio = 0;
  double mssim = 0;
};

// Every SSIM threshold of the defaults times `factor`; the schedule of the defaults, except that
// phase 1 grows the code-books on 5% of this small sample's texels (so both settings see the same
// texels in every phase).
RateQuality compress_and_evaluate(const MeasuredSample& sample, double factor) {
  CompressOptions options;
  const ParameterDictionary& d = options.config;
  nlohmann::json t;
  for (const char* key : {"p4", "p3", "m", "p2", "p1", "i2", "i1", "c"})
    t[key] = d.number(std::string("thresholds.ssim.") + key, 0.0, 1e6) * factor;
  options.config.merge(ParameterDictionary(
      nlohmann::json{{"thresholds", {{"ssim", t}}}, {"schedule", {{"phase1_fraction", 0.05}}}}, "test"));
  Database db;
  compress_material(db, sample, "m", options);
  quantize_new_rows(db);
  const auto bytes = serialize_database(db);
  const MeasuredSample decoded = reconstruct_sample(db, "m", sample);
  const EvaluationReport e = evaluate(sample, decoded);
  return {double(sample.raw_bytes()) / double(bytes.size()), e.mssim_y};
}

}  // namespace

TEST_CASE("stricter thresholds raise MSSIM and lower the compression ratio") {
  const MeasuredSample sample = synthesize({"leather", 16, 1, Dynamic::LDR, RenderPath::Auto, {}});
  const RateQuality loose = compress_and_evaluate(sample, 2.0);
  const RateQuality strict = compress_and_evaluate(sample, 0.25);
  MESSAGE("loose: ratio " << loose.ratio << ", MSSIM " << loose.mssim << "; strict: ratio " << strict.ratio
                          << ", MSSIM " << strict.mssim);
  CHECK(strict.mssim > loose.mssim);
  CHECK(strict.ratio < loose.ratio);
}
