// btfvq-server: the REST service (docs/api.md). This file only reads flags, wires the pieces,
// and turns SIGINT/SIGTERM into a graceful stop (running jobs go back to the queue).
#include <signal.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <cstdlib>
#include <iostream>
#include <thread>

#include <btfvq/error.h>
#include "server/http_server.h"
#include "server/server_config.h"
#include "server/service.h"

namespace {

constexpr const char* kUsage =
    "usage: btfvq-server [--listen HOST:PORT] [--data DIR] [--config FILE] [--input-root DIR] [--workers N]\n"
    "  defaults come from configs/server.json; BTFVQ_TOKEN sets the bearer token\n";

btfvq::server::ServerFlags parse_flags(int argc, char** argv) {
  btfvq::server::ServerFlags f;
  for (int i = 1; i < argc; ++i) {
    std::string flag = argv[i], value;
    if (flag == "--help" || flag == "-h") {
      std::cout << kUsage;
      std::exit(0);
    }
    if (auto eq = flag.find('='); eq != std::string::npos) {
      value = flag.substr(eq + 1);
      flag = flag.substr(0, eq);
    } else if (i + 1 < argc) {
      value = argv[++i];
    } else {
      throw btfvq::InputError(flag + " needs a value");
    }
    if (flag == "--listen") f.listen = value;
    else if (flag == "--data") f.data_dir = value;
    else if (flag == "--config") f.config_file = value;
    else if (flag == "--input-root") f.input_root = value;
    else if (flag == "--workers") {
      try {
        f.workers = std::stoi(value);
      } catch (const std::exception&) {
        throw btfvq::InputError("--workers: '" + value + "' is not an integer");
      }
    } else {
      throw btfvq::InputError("unknown flag '" + flag + "'");
    }
  }
  return f;
}

}  // namespace

int main(int argc, char** argv) {
  spdlog::set_default_logger(spdlog::stderr_color_mt("btfvq-server"));
  spdlog::set_pattern("[%Y-%m-%d %H:%M:%S.%e] [%l] %v");
  try {
    const auto config = btfvq::server::load_server_config(parse_flags(argc, argv));
    spdlog::set_level(spdlog::level::from_str(config.log_level));
    if (const char* level = std::getenv("BTFVQ_LOG")) spdlog::set_level(spdlog::level::from_str(level));

    // Block the stop signals in every thread; one thread waits for them.
    sigset_t signals;
    sigemptyset(&signals);
    sigaddset(&signals, SIGINT);
    sigaddset(&signals, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &signals, nullptr);

    btfvq::server::Service service(config.service, btfvq::server::make_pipeline_executor());
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
    std::cerr << "btfvq-server: error: " << e.what() << "\n" << kUsage;
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "btfvq-server: error: " << e.what() << "\n";
    return 1;
  }
}
