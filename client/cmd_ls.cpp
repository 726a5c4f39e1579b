// `btfvq ls`: the databases a server holds.
#include <cstdio>
#include <iostream>

#include "client/cli.h"
#include "client/http_client.h"
#include "client/progress_bar.h"

namespace btfvq::cli {
namespace {

int run_ls(const Args& args) {
  HttpClient client(remote_from(args));
  const auto reply = client.get_json("/v1/databases");
  if (args.has("json")) {
    std::cout << reply.dump(2) << "\n";
    return 0;
  }
  std::printf("%-24s %7s %9s %10s %8s  %s\n", "NAME", "VERSION", "MATERIALS", "SIZE", "RATIO", "SHA256");
  for (const auto& d : reply.value("databases", nlohmann::json::array())) {
    std::printf("%-24s %7lld %9zu %10s %8.1f  %.12s\n", d.value("name", "").c_str(),
                static_cast<long long>(d.value("version", int64_t(0))), d.value("materials", size_t(0)),
                ProgressBar::format_bytes(d.value("size", uint64_t(0))).c_str(), d.value("ratio", 0.0),
                d.value("sha256", "").c_str());
  }
  return 0;
}

CommandRegistrar reg({"ls", "ls --server URL [--json]", "list the databases on a server (versions, sizes, ratios)",
                      remote_options(), {{"json", "", "print the server's JSON reply"}}, run_ls});

}  // namespace
}  // namespace btfvq::cli
