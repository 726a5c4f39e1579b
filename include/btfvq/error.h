#pragma once
// Typed errors of the btfvq library. The library never exits the process: it throws one of these,
// and the thin shells (client/, server/) map them to exit codes or HTTP status codes in one place.
#include <stdexcept>
#include <string>

namespace btfvq {

// Base of everything the library throws on purpose. `code()` is a stable, machine-readable tag.
class Error : public std::runtime_error {
 public:
  Error(std::string code, const std::string& message) : std::runtime_error(message), code_(std::move(code)) {}
  const std::string& code() const { return code_; }

 private:
  std::string code_;
};

// The caller's input is wrong (bad file, bad name, missing direction, bad parameter): a 4xx.
class InputError : public Error {
 public:
  explicit InputError(const std::string& message, std::string code = "invalid_input")
      : Error(std::move(code), message) {}
};

// A configuration key is unknown, has the wrong type or is out of range.
class ConfigError : public InputError {
 public:
  explicit ConfigError(const std::string& message) : InputError(message, "invalid_config") {}
};

// A stored file (database, archive) is truncated or corrupted.
class CorruptError : public Error {
 public:
  explicit CorruptError(const std::string& message) : Error("corrupt", message) {}
};

// Something was looked up by name and is not there (material, database, job).
class NotFoundError : public Error {
 public:
  explicit NotFoundError(const std::string& message) : Error("not_found", message) {}
};

// An OpenCL call failed; the message names the call and the OpenCL error.
class DeviceError : public Error {
 public:
  explicit DeviceError(const std::string& message) : Error("device", message) {}
};

// An operation was cancelled by its caller (e.g. a job was deleted while running).
class CancelledError : public Error {
 public:
  explicit CancelledError(const std::string& message = "cancelled") : Error("cancelled", message) {}
};

}  // namespace btfvq
