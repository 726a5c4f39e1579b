#include "server/http_requests.h"

#include <algorithm>
#include <cctype>
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

namespace {

// "bytes FIRST-LAST/TOTAL" with FIRST <= LAST < TOTAL; the unknown total ("/*") is refused, since a
// resumable upload is verified against the sha256 of a file of known size.
ContentRange parse_content_range(const std::string& value) {
  const auto fail = [&]() -> ContentRange {
    throw InputError("Content-Range: '" + value + "' is not 'bytes FIRST-LAST/TOTAL' with FIRST <= LAST < TOTAL",
                     "invalid_request");
  };
  if (value.rfind("bytes ", 0) != 0) return fail();
  const std::string spec = value.substr(6);
  const auto dash = spec.find('-'), slash = spec.find('/');
  if (dash == std::string::npos || slash == std::string::npos || dash > slash) return fail();
  const auto number = [&](const std::string& t) -> uint64_t {
    if (t.empty() || t.size() > 19 || t.find_first_not_of("0123456789") != std::string::npos) fail();
    return std::stoull(t);
  };
  ContentRange r{number(spec.substr(0, dash)), number(spec.substr(dash + 1, slash - dash - 1)),
                 number(spec.substr(slash + 1))};
  if (r.first > r.last || r.last >= r.total) return fail();
  return r;
}

// A body that will not be stored is still read when modest, so that the client, which sends all
// of it before it reads the answer, gets the answer rather than a reset connection.
void drain(const httplib::Request& req, const httplib::ContentReader& reader, httplib::Response& res) {
  const std::string length = req.get_header_value("Content-Length");
  bool complete = !length.empty() && length.size() < 19 && std::stoull("0" + length) <= kMaxDrainedBytes;
  if (complete) complete = reader([](const char*, size_t) { return true; });
  if (!complete) res.set_header("Connection", "close");
}

}  // namespace

UploadRequest upload_request(const httplib::Request& req) {
  UploadRequest u;
  u.declared_size = header_number(req, "Content-Length");
  if (req.has_header("Content-Range")) u.range = parse_content_range(req.get_header_value("Content-Range"));
  u.sha256 = req.get_header_value("X-Sha256");
  std::transform(u.sha256.begin(), u.sha256.end(), u.sha256.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  return u;
}

json receive_upload(const httplib::Request& req, const httplib::ContentReader& reader, httplib::Response& res,
                    const std::function<std::unique_ptr<UploadSink>()>& begin) {
  std::unique_ptr<UploadSink> sink;
  try {
    sink = begin();
  } catch (const TooLargeError&) {
    res.set_header("Connection", "close");  // at once: the body is not worth reading
    throw;
  } catch (...) {
    drain(req, reader, res);
    throw;
  }
  uint64_t drained = 0;
  std::exception_ptr failed;
  const bool complete = reader([&](const char* data, size_t n) {
    if (!failed && !sink->too_large()) {
      try {
        if (sink->write(data, n)) return true;
      } catch (...) {
        failed = std::current_exception();  // the disk refused: the rest is read as past the limit
      }
    }
    drained += n;
    return drained < kMaxDrainedBytes;
  });
  if (failed || sink->too_large()) res.set_header("Connection", "close");
  if (failed) std::rethrow_exception(failed);
  if (sink->too_large())
    throw TooLargeError("upload exceeds the limit of " + std::to_string(sink->limit()) + " bytes");
  if (!complete) throw InputError("upload interrupted before the end of the body", "incomplete_upload");
  return sink->finish();
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
