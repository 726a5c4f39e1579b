#pragma once
// How errors reach an HTTP client (docs/api.md, "Errors"): the one mapping from btfvq::Error codes
// to status codes, and the one JSON error body {"error": {"code", "message"}}.
#include <exception>
#include <string>
#include <utility>

#include <nlohmann/json.hpp>

#include <btfvq/error.h>

namespace btfvq::server {

// `details` (an object) adds fields beside code and message, e.g. the `received` of upload_offset.
std::string error_body(const std::string& code, const std::string& message,
                       const nlohmann::json& details = nullptr);

int http_status(const Error& error);

// Any exception as (status, body): a btfvq::Error by its code, malformed JSON as a 400, anything
// else as a 500 "internal".
std::pair<int, std::string> error_response(std::exception_ptr error);

// The code for an error that httplib answered by itself, which carries only a status (no route,
// an unparsable Range, the payload limit).
std::string code_of_status(int status);

}  // namespace btfvq::server
