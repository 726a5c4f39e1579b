#pragma once
// Errors of the server beyond the library's. Each code has its status in http_errors.cpp.
#include <cstdint>

#include <btfvq/error.h>

namespace btfvq::server {

// Missing or wrong bearer token: 401.
class UnauthorizedError : public Error {
 public:
  explicit UnauthorizedError(const std::string& m) : Error("unauthorized", m) {}
};

// A well-formed request for something the server refuses (path outside the input root): 403.
class ForbiddenError : public Error {
 public:
  explicit ForbiddenError(const std::string& m) : Error("forbidden", m) {}
};

// The request conflicts with the current state (upload id in use, cancelling a finished job): 409.
class ConflictError : public Error {
 public:
  explicit ConflictError(const std::string& m) : Error("conflict", m) {}
};

// A piece of a resumable upload (PUT with Content-Range) that does not start where the upload
// stands: 409, with `received` in the body so that the client continues from there.
class UploadOffsetError : public Error {
 public:
  UploadOffsetError(const std::string& m, uint64_t received) : Error("upload_offset", m), received_(received) {}
  uint64_t received() const { return received_; }

 private:
  uint64_t received_;
};

// A Range that starts past the end of the content: 416.
class RangeNotSatisfiableError : public Error {
 public:
  explicit RangeNotSatisfiableError(const std::string& m) : Error("range_not_satisfiable", m) {}
};

// A request whose headers or body did not arrive in time (http_connections.h): 408.
class RequestTimeoutError : public Error {
 public:
  explicit RequestTimeoutError(const std::string& m) : Error("request_timeout", m) {}
};

// A body larger than the configured limit: 413.
class TooLargeError : public InputError {
 public:
  explicit TooLargeError(const std::string& m) : InputError(m, "too_large") {}
};

}  // namespace btfvq::server
