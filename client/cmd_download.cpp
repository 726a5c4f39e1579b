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
  bar.finish(ProgressBar::format_bytes(r.size) + (r.resumed_from ? " (resumed at " + ProgressBar::format_bytes(r.resumed_from) + ")" : "") +
             ", sha256 verified");
  std::cout << out << " " << r.sha256 << " version " << r.version << "\n";
  return 0;
}

CommandRegistrar reg({"download", "download --server URL NAME --out FILE [--version N]",
                      "download a database (resumes FILE.part, verifies the sha256)",
                      remote_options({{"out", "FILE", "where to write; a FILE.part left by a broken download is resumed"},
                                      {"version", "N", "that version instead of the newest"}}),
                      {}, run_download});

}  // namespace
}  // namespace btfvq::cli
