#include "server/http_requests.h"

#include <algorithm>
#include <string>

#include <btfvq/error.h>
#include "server/errors.h"
#include "server/numbers.h"

namespace btfvq::server {
using nlohmann::json;

namespace {

constexpr uint64_t kMaxDrainedBytes = uint64_t(64) << 20;

double number_param(const char* key, const std::string& text) {
  const auto v = whole_number(text);
  if (!v) throw InputError(std::string(key) + ": '" + text + "' is not a number");
  return *v;
}

}  // namespace

json read_json_body(const httplib::ContentReader& reader, uint64_t limit) {
  std::string body;
  bool too_large = false;
  reader([&](const char* data, size_t n) {
    if (body.size() + n > limit) {
      too_large = true;
      return false;
    }
    body.append(data, n);
    return true;
  });
  if (too_large) throw TooLargeError("request body exceeds " + std::to_string(limit) + " bytes");
  try {
    return json::parse(body);
  } catch (const json::parse_error& e) {
    throw InputError(std::string("request body is not valid JSON: ") + e.what(), "invalid_json");
  }
}

json receive_upload(const httplib::Request& req, const httplib::ContentReader& reader, httplib::Response& res,
                    UploadSink& sink) {
  uint64_t drained = 0;
  const bool complete = reader([&](const char* data, size_t n) {
    if (!sink.too_large() && sink.write(data, n)) return true;
    if (!sink.too_large()) return false;
    drained += n;
    return drained < kMaxDrainedBytes;
  });
  if (sink.too_large()) {
    res.set_header("Connection", "close");
    throw TooLargeError("upload exceeds the limit of " + std::to_string(sink.limit()) + " bytes");
  }
  if (!complete) throw InputError("upload interrupted before the end of the body", "incomplete_upload");
  return sink.finish(req.get_header_value("X-Sha256"));
}

std::optional<uint64_t> header_number(const httplib::Request& req, const char* name) {
  if (!req.has_header(name)) return std::nullopt;
  try {
    return std::stoull(req.get_header_value(name));
  } catch (const std::exception&) {
    throw InputError(std::string(name) + ": not a number");
  }
}

std::optional<int64_t> version_query(const httplib::Request& req) {
  if (!req.has_param("version")) return std::nullopt;
  const std::string v = req.get_param_value("version");
  const auto n = whole_integer(v);
  if (!n || *n < 1) throw InputError("version: '" + v + "' is not a version number");
  return n;
}

PreviewOptions preview_query(const httplib::Request& req) {
  PreviewOptions o;
  if (req.has_param("scene")) o.scene = parse_preview_scene(req.get_param_value("scene"));
  if (req.has_param("size")) o.size = int(std::clamp(number_param("size", req.get_param_value("size")), -1.0, 1e6));
  if (req.has_param("light")) {
    const std::string l = req.get_param_value("light");
    const auto comma = l.find(',');
    if (comma == std::string::npos) throw InputError("light: '" + l + "' is not THETA,PHI in degrees");
    o.lights = {{{number_param("light", l.substr(0, comma)), number_param("light", l.substr(comma + 1))}, 1.0}};
  }
  if (req.has_param("env") && req.get_param_value("env") != "0") o.lights = preview_environment();
  return o;
}

}  // namespace btfvq::server
