#include "pipeline/runtime/opencl_runtime.h"

#include <spdlog/spdlog.h>

#include <cstdlib>
#include <memory>

#include "pipeline/runtime/resources.h"

namespace btfvq {

std::string opencl_error_name(int code) {
  static const std::map<int, const char*> names = {
      {0, "CL_SUCCESS"},
      {-1, "CL_DEVICE_NOT_FOUND"},
      {-2, "CL_DEVICE_NOT_AVAILABLE"},
      {-3, "CL_COMPILER_NOT_AVAILABLE"},
      {-4, "CL_MEM_OBJECT_ALLOCATION_FAILURE"},
      {-5, "CL_OUT_OF_RESOURCES"},
      {-6, "CL_OUT_OF_HOST_MEMORY"},
      {-7, "CL_PROFILING_INFO_NOT_AVAILABLE"},
      {-8, "CL_MEM_COPY_OVERLAP"},
      {-9, "CL_IMAGE_FORMAT_MISMATCH"},
      {-10, "CL_IMAGE_FORMAT_NOT_SUPPORTED"},
      {-11, "CL_BUILD_PROGRAM_FAILURE"},
      {-12, "CL_MAP_FAILURE"},
      {-13, "CL_MISALIGNED_SUB_BUFFER_OFFSET"},
      {-14, "CL_EXEC_STATUS_ERROR_FOR_EVENTS_IN_WAIT_LIST"},
      {-15, "CL_COMPILE_PROGRAM_FAILURE"},
      {-16, "CL_LINKER_NOT_AVAILABLE"},
      {-17, "CL_LINK_PROGRAM_FAILURE"},
      {-18, "CL_DEVICE_PARTITION_FAILED"},
      {-19, "CL_KERNEL_ARG_INFO_NOT_AVAILABLE"},
      {-30, "CL_INVALID_VALUE"},
      {-31, "CL_INVALID_DEVICE_TYPE"},
      {-32, "CL_INVALID_PLATFORM"},
      {-33, "CL_INVALID_DEVICE"},
      {-34, "CL_INVALID_CONTEXT"},
      {-35, "CL_INVALID_QUEUE_PROPERTIES"},
      {-36, "CL_INVALID_COMMAND_QUEUE"},
      {-37, "CL_INVALID_HOST_PTR"},
      {-38, "CL_INVALID_MEM_OBJECT"},
      {-39, "CL_INVALID_IMAGE_FORMAT_DESCRIPTOR"},
      {-40, "CL_INVALID_IMAGE_SIZE"},
      {-41, "CL_INVALID_SAMPLER"},
      {-42, "CL_INVALID_BINARY"},
      {-43, "CL_INVALID_BUILD_OPTIONS"},
      {-44, "CL_INVALID_PROGRAM"},
      {-45, "CL_INVALID_PROGRAM_EXECUTABLE"},
      {-46, "CL_INVALID_KERNEL_NAME"},
      {-47, "CL_INVALID_KERNEL_DEFINITION"},
      {-48, "CL_INVALID_KERNEL"},
      {-49, "CL_INVALID_ARG_INDEX"},
      {-50, "CL_INVALID_ARG_VALUE"},
      {-51, "CL_INVALID_ARG_SIZE"},
      {-52, "CL_INVALID_KERNEL_ARGS"},
      {-53, "CL_INVALID_WORK_DIMENSION"},
      {-54, "CL_INVALID_WORK_GROUP_SIZE"},
      {-55, "CL_INVALID_WORK_ITEM_SIZE"},
      {-56, "CL_INVALID_GLOBAL_OFFSET"},
      {-57, "CL_INVALID_EVENT_WAIT_LIST"},
      {-58, "CL_INVALID_EVENT"},
      {-59, "CL_INVALID_OPERATION"},
      {-60, "CL_INVALID_GL_OBJECT"},
      {-61, "CL_INVALID_BUFFER_SIZE"},
      {-62, "CL_INVALID_MIP_LEVEL"},
      {-63, "CL_INVALID_GLOBAL_WORK_SIZE"},
      {-64, "CL_INVALID_PROPERTY"},
      {-1001, "CL_PLATFORM_NOT_FOUND_KHR"},
  };
  auto it = names.find(code);
  return it != names.end() ? it->second : "OpenCL error " + std::to_string(code);
}

namespace {

std::mutex g_device_mutex;
std::string g_preference = "auto";
std::unique_ptr<ComputeDevice> g_device;

std::string effective_preference() {
  const char* env = std::getenv("BTFVQ_DEVICE");
  return (env && *env) ? std::string(env) : g_preference;
}

void check_preference(const std::string& p) {
  if (p != "auto" && p != "opencl" && p != "cpu-reference")
    throw ConfigError("device must be one of auto, opencl, cpu-reference (got '" + p + "')");
}

}  // namespace

ComputeDevice& ComputeDevice::get() {
  std::lock_guard<std::mutex> lock(g_device_mutex);
  if (!g_device) g_device.reset(new ComputeDevice(effective_preference()));
  return *g_device;
}

void ComputeDevice::configure(const std::string& preference) {
  check_preference(preference);
  std::lock_guard<std::mutex> lock(g_device_mutex);
  if (g_preference == preference && g_device) return;
  g_preference = preference;
  g_device.reset();
}

ComputeDevice::ComputeDevice(const std::string& preference) {
  check_preference(preference);
  if (preference == "cpu-reference") {
    description_ = "C++ reference path (selected by configuration)";
    spdlog::info("compute: {}", description_);
    return;
  }
  std::string why;
  try {
    std::vector<cl::Platform> platforms;
    cl::Platform::get(&platforms);
    // Prefer a CPU device (PoCL here), then anything else that exists.
    for (cl_device_type type : {cl_device_type(CL_DEVICE_TYPE_CPU), cl_device_type(CL_DEVICE_TYPE_ALL)}) {
      for (auto& platform : platforms) {
        std::vector<cl::Device> devices;
        try {
          platform.getDevices(type, &devices);
        } catch (const cl::Error&) {
          continue;
        }
        if (devices.empty()) continue;
        device_ = devices.front();
        context_ = cl::Context(device_);
        queue_ = cl::CommandQueue(context_, device_);
        backend_ = Backend::OpenCL;
        description_ = "OpenCL: " + platform.getInfo<CL_PLATFORM_NAME>() + " / " + device_.getInfo<CL_DEVICE_NAME>();
        spdlog::debug("compute: {}", description_);
        return;
      }
    }
    why = "no OpenCL platform with a device was found";
  } catch (const cl::Error& e) {
    why = std::string("OpenCL is not usable (") + e.what() + ": " + opencl_error_name(e.err()) + ")";
  }
  if (preference == "opencl") throw DeviceError("BTFVQ_DEVICE=opencl but " + why);
  description_ = "C++ reference path (" + why + ")";
  spdlog::warn("compute: {}; using the C++ reference path, which is slower", why);
}

void ComputeDevice::require_opencl() const {
  if (backend_ != Backend::OpenCL) throw DeviceError("OpenCL is not in use: " + description_);
}

cl::Context& ComputeDevice::context() {
  require_opencl();
  return context_;
}

cl::CommandQueue& ComputeDevice::queue() {
  require_opencl();
  return queue_;
}

cl::Device& ComputeDevice::device() {
  require_opencl();
  return device_;
}

cl::Kernel ComputeDevice::kernel(const std::string& file, const std::string& entry) {
  require_opencl();
  std::lock_guard<std::mutex> lock(programs_mutex_);
  auto it = programs_.find(file);
  if (it == programs_.end()) {
    const std::string& source = embedded_resource("kernels/" + file);
    cl::Program program(context_, source);
    try {
      program.build(std::vector<cl::Device>{device_}, "-cl-std=CL1.2");
    } catch (const cl::Error& e) {
      std::string log;
      try {
        log = program.getBuildInfo<CL_PROGRAM_BUILD_LOG>(device_);
      } catch (const cl::Error&) {
      }
      throw DeviceError("building kernels/" + file + " failed with " + opencl_error_name(e.err()) + ":\n" + log);
    }
    it = programs_.emplace(file, program).first;
  }
  return opencl_call(("creating kernel " + entry).c_str(), [&] { return cl::Kernel(it->second, entry.c_str()); });
}

cl::Buffer ComputeDevice::upload_bytes(const void* data, size_t bytes, cl_mem_flags flags) {
  require_opencl();
  return opencl_call("clCreateBuffer", [&] {
    // A zero-sized buffer is invalid in OpenCL; keep one byte so empty inputs still work.
    if (bytes == 0) return cl::Buffer(context_, flags, 1);
    return cl::Buffer(context_, flags | CL_MEM_COPY_HOST_PTR, bytes, const_cast<void*>(data));
  });
}

cl::Buffer ComputeDevice::allocate(size_t bytes, cl_mem_flags flags) {
  require_opencl();
  return opencl_call("clCreateBuffer", [&] { return cl::Buffer(context_, flags, bytes ? bytes : 1); });
}

void ComputeDevice::download_bytes(const cl::Buffer& buffer, void* out, size_t bytes) {
  require_opencl();
  if (bytes == 0) return;
  opencl_call("clEnqueueReadBuffer", [&] { queue_.enqueueReadBuffer(buffer, CL_TRUE, 0, bytes, out); });
}

}  // namespace btfvq
