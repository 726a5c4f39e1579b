#pragma once
// The one OpenCL runtime wrapper: which device computes, its context and queue, a cache of built
// programs (sources embedded from kernels/*.cl), and OpenCL errors turned into DeviceError.
//
// Every kernel has a plain C++ reference. Which one runs is decided once per process:
//   BTFVQ_DEVICE=cpu-reference | opencl | auto   (environment, wins over the config key "device")
// "auto" (default) uses OpenCL when a platform with a device exists and otherwise falls back to the
// reference path, saying so in one log line.
#include <CL/opencl.hpp>

#include <map>
#include <mutex>
#include <string>
#include <vector>

#include <btfvq/error.h>

namespace btfvq {

enum class Backend { OpenCL, Reference };

// Name of an OpenCL status code, e.g. -5 -> "CL_OUT_OF_RESOURCES".
std::string opencl_error_name(int code);

class ComputeDevice {
 public:
  // The process-wide device, created on first use from the environment (or the last configure()).
  static ComputeDevice& get();
  // Sets the preference ("auto", "opencl", "cpu-reference") used when the device is (re)created.
  // The environment variable BTFVQ_DEVICE still wins. Throws ConfigError on an unknown value.
  static void configure(const std::string& preference);

  Backend backend() const { return backend_; }
  bool uses_opencl() const { return backend_ == Backend::OpenCL; }
  // Human-readable description: platform and device name, or why the reference path is used.
  const std::string& description() const { return description_; }

  // Only valid when uses_opencl(); throw DeviceError otherwise.
  cl::Context& context();
  cl::CommandQueue& queue();
  cl::Device& device();

  // A fresh kernel object for `entry` in kernels/`file` (e.g. "resample.cl"). The program is built
  // once and cached; a build failure throws DeviceError with the build log.
  cl::Kernel kernel(const std::string& file, const std::string& entry);

  template <class T>
  cl::Buffer upload(const std::vector<T>& data, cl_mem_flags flags = CL_MEM_READ_ONLY) {
    return upload_bytes(data.data(), data.size() * sizeof(T), flags);
  }
  cl::Buffer upload_bytes(const void* data, size_t bytes, cl_mem_flags flags = CL_MEM_READ_ONLY);
  cl::Buffer allocate(size_t bytes, cl_mem_flags flags = CL_MEM_READ_WRITE);
  template <class T>
  void download(const cl::Buffer& buffer, std::vector<T>& out) {
    download_bytes(buffer, out.data(), out.size() * sizeof(T));
  }
  void download_bytes(const cl::Buffer& buffer, void* out, size_t bytes);

  ComputeDevice(const ComputeDevice&) = delete;
  ComputeDevice& operator=(const ComputeDevice&) = delete;

 private:
  explicit ComputeDevice(const std::string& preference);
  void require_opencl() const;

  Backend backend_ = Backend::Reference;
  std::string description_;
  cl::Context context_;
  cl::Device device_;
  cl::CommandQueue queue_;
  std::mutex programs_mutex_;
  std::map<std::string, cl::Program> programs_;
};

// Maps `buffer` for the host (PoCL's CPU device hands out its own memory: no copy) and unmaps it
// when done.
template <class T>
class Mapped {
 public:
  Mapped(cl::CommandQueue& queue, const cl::Buffer& buffer, cl_map_flags flags, size_t count)
      : queue_(queue), buffer_(buffer) {
    ptr_ = static_cast<T*>(queue.enqueueMapBuffer(buffer, CL_TRUE, flags, 0, count * sizeof(T)));
  }
  ~Mapped() {
    try {
      queue_.enqueueUnmapMemObject(buffer_, ptr_);
    } catch (const cl::Error&) {  // nothing sensible to do in a destructor; the buffer stays mapped
    }
  }
  Mapped(const Mapped&) = delete;
  Mapped& operator=(const Mapped&) = delete;
  T* get() const { return ptr_; }

 private:
  cl::CommandQueue& queue_;
  const cl::Buffer& buffer_;
  T* ptr_ = nullptr;
};


// Runs `f`, turning a cl::Error into a DeviceError that names `what` and the OpenCL error.
template <class F>
auto opencl_call(const char* what, F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (const cl::Error& e) {
    throw DeviceError(std::string(what) + ": " + e.what() + " failed with " + opencl_error_name(e.err()));
  }
}

// Rounds n up to a multiple of `multiple` (global work sizes).
inline size_t round_up(size_t n, size_t multiple) { return (n + multiple - 1) / multiple * multiple; }

}  // namespace btfvq
