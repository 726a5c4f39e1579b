// btfvq-server: the REST service (docs/api.md). This file only reads flags, wires the pieces,
// and turns SIGINT/SIGTERM into a graceful stop (running jobs go back to the queue).
#include <signal.h>
#ifdef __GLIBC__
#include <malloc.h>
#endif
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <cstdlib>
#include <iostream>
#include <string>
#include <thread>
#include <vector>

#include <btfvq/error.h>
#include "pipeline/util/args.h"
#include "server/http_server.h"
#include "server/server_config.h"
#include "server/service.h"

namespace {

const btfvq::ArgSpec kSpec{
    "btfvq-server",
    "btfvq-server [--listen HOST:PORT] [--data DIR] [--config FILE] [--input-root DIR] [--workers N]",
    "the btfvq REST service (docs/api.md)",
    {{"listen", "HOST:PORT", "the address to listen on"},
     {"data", "DIR", "the data directory (SQLite and blobs)"},
     {"config", "FILE", "settings over configs/server.json"},
     {"input-root", "DIR", "the folder below which jobs may name server-side paths"},
     {"workers", "N", "how many jobs run at once"}},
    {},
    /*positionals=*/false,
    "defaults come from configs/server.json; BTFVQ_TOKEN sets the bearer token"};

btfvq::server::ServerFlags flags_of(const btfvq::Args& args) {
  btfvq::server::ServerFlags f;
  f.listen = args.get("listen");
  f.data_dir = args.get("data");
  f.config_file = args.get("config");
  f.input_root = args.get("input-root");
  if (args.has("workers")) f.workers = args.integer("workers", 0);
  return f;
}

}  // namespace

int main(int argc, char** argv) {
#ifdef __GLIBC__
  // At most 2 malloc arenas (glibc's default is 8 per core), unless MALLOC_ARENA_MAX says otherwise.
  // With the default, the HTTP threads and the compressions spread over many arenas, and what a
  // finished compression freed stayed resident, fragmented among them: the soak of
  // bench/bench_soak.py (50 clients, a small job every 20 s) measured the resident memory growing
  // +55% from the 2nd to the 10th minute (375 -> 582 MiB, median of each minute), and +2% with 2
  // arenas (flat at 212 MiB, jobs included), at the same latencies.
  if (!std::getenv("MALLOC_ARENA_MAX")) mallopt(M_ARENA_MAX, 2);
#endif
  spdlog::set_default_logger(spdlog::stderr_color_mt("btfvq-server"));
  spdlog::set_pattern("[%Y-%m-%d %H:%M:%S.%e] [%l] %v");
  try {
    const btfvq::Args args = btfvq::parse_args(kSpec, std::vector<std::string>(argv + 1, argv + argc));
    if (args.has("help")) {
      std::cout << btfvq::help_text(kSpec);
      return 0;
    }
    const auto config = btfvq::server::load_server_config(flags_of(args));
    spdlog::set_level(spdlog::level::from_str(config.log_level));
    if (const char* level = std::getenv("BTFVQ_LOG")) spdlog::set_level(spdlog::level::from_str(level));

    // Block the stop signals in every thread; one thread waits for them.
    sigset_t signals;
    sigemptyset(&signals);
    sigaddset(&signals, SIGINT);
    sigaddset(&signals, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &signals, nullptr);

    btfvq::server::Service service(config.service, config.executor == "slurm"
                                                       ? btfvq::server::make_slurm_executor(config.slurm)
                                                       : btfvq::server::make_pipeline_executor());
    if (config.executor == "slurm")
      spdlog::info("executor: slurm (partition '{}', shared folder {})", config.slurm.partition, config.slurm.shared_folder);
    service.start();
    btfvq::server::HttpServer http(service, config.http);
    const int port = http.bind(config.host, config.port);
    if (config.host != "127.0.0.1" && config.host != "localhost" && config.http.token.empty())
      spdlog::warn("listening on {} without a token: anyone who can reach this port can submit jobs", config.host);
    std::cerr << "btfvq-server: listening on http://" << config.host << ":" << port << std::endl;

    std::thread waiter([&] {
      int sig = 0;
      sigwait(&signals, &sig);
      spdlog::info("signal {}: shutting down", sig);
      http.stop();
    });
    http.run();
    service.stop();
    waiter.join();
    spdlog::info("stopped");
    return 0;
  } catch (const btfvq::InputError& e) {
    std::cerr << "btfvq-server: error: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "btfvq-server: error: " << e.what() << "\n";
    return 1;
  }
}
