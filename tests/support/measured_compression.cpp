#include "support/measured_compression.h"

#include "pipeline/decode/reconstruct.h"
#include "pipeline/encode/compress.h"
#include "pipeline/format/database.h"
#include "pipeline/metrics/metrics.h"

namespace btfvq::test {

Measured compress_and_measure(const MeasuredSample& sample, const ParameterDictionary& config) {
  Database db;
  CompressOptions options;
  options.config = config;
  compress_material(db, sample, "m", options);
  quantize_new_rows(db);  // as written: the file holds quantized rows, and the decoder reads those
  return {serialize_database(db).size(), evaluate(sample, reconstruct_sample(db, "m", sample)).mssim_y};
}

}  // namespace btfvq::test
