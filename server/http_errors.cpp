#include "server/http_errors.h"

#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <iterator>
#include <string_view>

#include "server/errors.h"

namespace btfvq::server {
namespace {

// The codes with a status of their own; any other InputError is a 400, any other Error a 500.
constexpr std::pair<std::string_view, int> kStatusOfCode[] = {
    {"unauthorized", 401}, {"forbidden", 403}, {"not_found", 404},
    {"request_timeout", 408},                  {"conflict", 409},
    {"cancelled", 409},    {"upload_offset", 409},
    {"too_large", 413},    {"range_not_satisfiable", 416},
    {"unavailable", 503},  {"no_space", 507}};

// The statuses that httplib sends by itself, named as the table above names them.
constexpr int kHttplibStatuses[] = {404, 413, 416};

}  // namespace

std::string error_body(const std::string& code, const std::string& message, const nlohmann::json& details) {
  nlohmann::json error = {{"code", code}, {"message", message}};
  if (details.is_object()) error.update(details);
  // A message may quote what the client sent (a path, an id): bytes that are not UTF-8 become U+FFFD
  // rather than an exception in the middle of answering (found by the fuzz of bench/bench_soak.py).
  return nlohmann::json{{"error", error}}.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

int http_status(const Error& error) {
  for (const auto& [code, status] : kStatusOfCode)
    if (error.code() == code) return status;
  return dynamic_cast<const InputError*>(&error) ? 400 : 500;
}

std::pair<int, std::string> error_response(std::exception_ptr error) {
  try {
    std::rethrow_exception(error);
  } catch (const UploadOffsetError& e) {
    return {http_status(e), error_body(e.code(), e.what(), {{"received", e.received()}})};
  } catch (const Error& e) {
    return {http_status(e), error_body(e.code(), e.what())};
  } catch (const nlohmann::json::exception& e) {
    return {400, error_body("invalid_json", std::string("request body: ") + e.what())};
  } catch (const std::exception& e) {
    spdlog::error("internal error: {}", e.what());
    return {500, error_body("internal", e.what())};
  } catch (...) {
    return {500, error_body("internal", "unknown error")};
  }
}

std::string code_of_status(int status) {
  if (std::find(std::begin(kHttplibStatuses), std::end(kHttplibStatuses), status) != std::end(kHttplibStatuses))
    for (const auto& [code, s] : kStatusOfCode)
      if (s == status) return std::string(code);
  return "http_" + std::to_string(status);
}

}  // namespace btfvq::server
