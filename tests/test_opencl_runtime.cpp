#include <doctest/doctest.h>

#include <cstdlib>

#include "pipeline/runtime/opencl_runtime.h"
#include "pipeline/runtime/resources.h"
#include "support/test_paths.h"

using namespace btfvq;

TEST_CASE("kernels and configs are embedded in the binary") {
  CHECK(embedded_resource("kernels/selftest.cl").find("saxpy") != std::string::npos);
  CHECK(embedded_resource("configs/pipeline.json").find("grid") != std::string::npos);
  CHECK_THROWS_AS(embedded_resource("kernels/nope.cl"), NotFoundError);
}

TEST_CASE("PoCL is the default device here and runs an embedded kernel like its reference") {
  ComputeDevice::configure("auto");
  auto& dev = ComputeDevice::get();
  REQUIRE_MESSAGE(dev.uses_opencl(), dev.description());
  std::vector<float> x(1000), y(1000), expect(1000);
  for (size_t i = 0; i < x.size(); ++i) {
    x[i] = float(i) * 0.5f;
    y[i] = 3.0f - float(i);
    expect[i] = 2.0f * x[i] + y[i];  // the C++ reference of saxpy
  }
  auto bx = dev.upload(x);
  auto by = dev.upload(y, CL_MEM_READ_WRITE);
  auto k = dev.kernel("selftest.cl", "saxpy");
  k.setArg(0, 2.0f);
  k.setArg(1, bx);
  k.setArg(2, by);
  k.setArg(3, cl_uint(x.size()));
  dev.queue().enqueueNDRangeKernel(k, cl::NullRange, cl::NDRange(round_up(x.size(), 64)));
  dev.download(by, y);
  for (size_t i = 0; i < y.size(); ++i) CHECK(y[i] == doctest::Approx(expect[i]));
}

TEST_CASE("OpenCL errors become DeviceError naming the error") {
  auto& dev = ComputeDevice::get();
  REQUIRE(dev.uses_opencl());
  CHECK(opencl_error_name(-5) == "CL_OUT_OF_RESOURCES");
  CHECK(opencl_error_name(-46) == "CL_INVALID_KERNEL_NAME");
  try {
    dev.kernel("selftest.cl", "no_such_kernel");
    FAIL("expected DeviceError");
  } catch (const DeviceError& e) {
    CHECK(std::string(e.what()).find("CL_INVALID_KERNEL_NAME") != std::string::npos);
  }
}

TEST_CASE("cpu-reference is selectable and unknown preferences are rejected") {
  ComputeDevice::configure("cpu-reference");
  CHECK_FALSE(ComputeDevice::get().uses_opencl());
  CHECK_THROWS_AS(ComputeDevice::get().queue(), DeviceError);
  CHECK_THROWS_AS(ComputeDevice::configure("gpu-please"), ConfigError);
  ComputeDevice::configure("auto");
  CHECK(ComputeDevice::get().uses_opencl());
}

TEST_CASE("without any OpenCL platform the tool falls back to the reference path with one log line") {
  std::string out;
  // An empty vendor directory hides every ICD from the loader: no platform exists for this process.
  const auto empty = btfvq::test::scratch_dir("no-icd");
  const int rc = btfvq::test::run_command("env -u BTFVQ_DEVICE OCL_ICD_VENDORS=" + empty.string() + " " +
                                              (btfvq::test::bin_dir() / "btfvq").string() + " device",
                                          &out);
  CHECK(rc == 0);
  CHECK(out.find("C++ reference path") != std::string::npos);
  size_t warnings = 0;
  for (size_t p = out.find("warning"); p != std::string::npos; p = out.find("warning", p + 1)) ++warnings;
  CHECK(warnings == 1);
}
