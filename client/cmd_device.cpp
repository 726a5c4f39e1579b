// `btfvq device`: which compute path this machine uses, so a user can see why a run is slow.
#include <iostream>

#include "client/cli.h"
#include "pipeline/runtime/opencl_runtime.h"

namespace btfvq::cli {
namespace {

int run_device(const Args&) {
  std::cout << ComputeDevice::get().description() << "\n";
  return 0;
}

CommandRegistrar reg({"device", "device", "print the compute device in use (OpenCL or the C++ reference path)", {}, {},
                      run_device});

}  // namespace
}  // namespace btfvq::cli
