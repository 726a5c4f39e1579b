#pragma once
// Errors that only the HTTP shell raises. Each maps to one status code in routes.cpp.
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

// A body larger than the configured limit: 413.
class TooLargeError : public InputError {
 public:
  explicit TooLargeError(const std::string& m) : InputError(m, "too_large") {}
};

}  // namespace btfvq::server
