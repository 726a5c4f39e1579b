// `btfvq download`: fetches the newest (or a given) version of a database, resumably.
#include <iostream>

#include "client/cli.h"
#include "client/http_client.h"
#include "client/progress_bar.h"
#include <btfvq/error.h>

namespace btfvq::cli {
namespace {

int run_download(const Args& args) {
  if (args.positional.size() != 1) throw InputError("usage: btfvq download --server URL NAME --out FILE");
  const std::string name = args.positional[0], out = args.require("out");
  std::optional<int64_t> version;
  if (args.has("version")) version = args.integer("version", 0, 1, 2147483647);
  HttpClient client(remote_from(args));
  ProgressBar bar("download " + name);
  const auto r = client.download_database(name, out, version,
                                          [&](uint64_t done, uint64_t total) { bar.update_bytes(done, total); });
  std::string how = r.resumed_from ? " (resumed at " + ProgressBar::format_bytes(r.resumed_from) + ")" : "";
  if (r.delta_from)
    how = r.delta_from == r.version ? " (already at version " + std::to_string(r.version) + ")"
                                    : " (delta from version " + std::to_string(r.delta_from) + ")";
  bar.finish(ProgressBar::format_bytes(r.size) + how + ", " + ProgressBar::format_bytes(r.transferred) +
             " transferred, sha256 verified");
  if (!r.fallback.empty()) std::cerr << "btfvq download: no delta download (" << r.fallback << "); downloaded in full\n";
  // The line scripts read: FILE SHA256 version N transferred BYTES [delta-from M]
  std::cout << out << " " << r.sha256 << " version " << r.version << " transferred " << r.transferred;
  if (r.delta_from) std::cout << " delta-from " << r.delta_from;
  std::cout << "\n";
  return 0;
}

CommandRegistrar reg({"download", "download --server URL NAME --out FILE [--version N]",
                      "download a database (resumes FILE.part; an existing FILE of an older version fetches only what is new; verifies the sha256)",
                      remote_options({{"out", "FILE", "where to write; a FILE.part left by a broken download is resumed, an existing FILE is updated by a delta download"},
                                      {"version", "N", "that version instead of the newest"}}),
                      {}, run_download});

}  // namespace
}  // namespace btfvq::cli
