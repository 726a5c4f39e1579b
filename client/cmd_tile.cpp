// `btfvq tile`: phase-3 tiles of one input computed from files only, on any machine with the binary
// and the shared folder (the server's Slurm executor runs it as an array job; docs/cluster.md).
// A thin shell over compute_tile_part (pipeline/encode/tile_parts.h).
#include <iostream>
#include <string>

#include "client/cli.h"
#include "pipeline/encode/compress.h"
#include "pipeline/encode/tile_parts.h"

namespace btfvq::cli {
namespace {

// "A-B" (inclusive) or "A": tiles [A, B + 1).
std::pair<size_t, size_t> parse_tiles(const std::string& text) {
  const auto dash = text.find('-');
  const std::string a = text.substr(0, dash), b = dash == std::string::npos ? a : text.substr(dash + 1);
  const double lo = parse_number(a, "--tiles", 0, 1e12), hi = parse_number(b, "--tiles", 0, 1e12);
  if (lo != double(size_t(lo)) || hi != double(size_t(hi)) || hi < lo)
    throw InputError("--tiles must be A-B with whole numbers A <= B (got '" + text + "')");
  return {size_t(lo), size_t(hi) + 1};
}

int run_tile(const Args& a) {
  const auto [first, end] = parse_tiles(a.require("tiles"));
  const std::string out = a.require("out");
  const TilePart p = compute_tile_part(a.require("codebooks"), a.require("sample"), first, end, out);
  check_tile_part(out);  // what the merge will check: a part this command wrote passes it
  std::cout << "tiles " << p.first << "-" << p.end - 1 << ": " << p.bytes << " bytes, sha256 " << p.sha256 << ", P4 "
            << p.p4_from << " -> " << p.p4_end << ", load " << p.load_seconds << " s, tiles " << p.seconds << " s\n";
  return 0;
}

CommandRegistrar reg({"tile", "tile --codebooks SNAPSHOT --sample S.raw --tiles A-B --out PART",
                      "compute phase-3 tiles A..B of a compression from a snapshot of its checkpoint (cluster nodes)",
                      {{"codebooks", "SNAPSHOT", "folder with the frozen code-books (state.ckpt, tiles.log, config.json, fingerprint)"},
                       {"sample", "S.raw", "the input's texels as the server wrote them"},
                       {"tiles", "A-B", "phase-3 tiles, numbered from 0, both ends included"},
                       {"out", "PART", "the part to write (and PART.json, its manifest, once complete)"}},
                      {}, run_tile});

}  // namespace
}  // namespace btfvq::cli
