// `btfvq decode`: a material reconstructed at the 81 x 81 measured directions, written in the
// UBO2003 layout, so that a decoded material can be fed back into `btfvq compress` and the benches.
#include <iostream>

#include "client/cli.h"
#include "pipeline/format/database.h"
#include "pipeline/decode/reconstruct.h"
#include "pipeline/io/sample_io.h"

namespace btfvq::cli {
namespace {

int run_decode(const Args& a) {
  if (a.positional.size() != 1) throw InputError("usage: btfvq decode DB --material NAME --out SAMPLE(.zip|dir)");
  const Database db = read_database(a.positional[0]);
  const std::string name = a.require("material");
  const MeasuredSample sample = reconstruct_bonn(db, name);
  WriteOptions options;
  options.jpeg_quality = a.integer("quality", 95, 1, 100);
  write_sample(sample, a.require("out"), options);
  std::cout << "wrote " << sample.pair_count() << " images of " << sample.width() << " x " << sample.height() << " to "
            << a.require("out") << "\n";
  return 0;
}

CommandRegistrar reg({"decode", "decode DB --material NAME --out SAMPLE(.zip|dir) [--quality Q]",
                      "write a material decoded at the 81 x 81 measured directions in the UBO2003 layout",
                      {{"material", "NAME", "the material to decode"},
                       {"out", "SAMPLE", "where to write: a .zip or a folder"},
                       {"quality", "Q", "JPEG quality, 1 to 100 (default 95)"}},
                      {}, run_decode});

}  // namespace
}  // namespace btfvq::cli
