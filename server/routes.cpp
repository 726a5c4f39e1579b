// REST routes: each handler is a line or two over the Service. Everything that can go wrong is
// thrown as a btfvq::Error and turned into a status code by error_response(), the one place.
#include <httplib.h>
#include <spdlog/spdlog.h>

#include <chrono>

#include "server/errors.h"
#include "server/http_server.h"

namespace btfvq::server {
using nlohmann::json;

std::pair<int, std::string> error_response(std::exception_ptr error) {
  auto body = [](const std::string& code, const std::string& message) {
    return json{{"error", {{"code", code}, {"message", message}}}}.dump();
  };
  try {
    std::rethrow_exception(error);
  } catch (const UnauthorizedError& e) {
    return {401, body(e.code(), e.what())};
  } catch (const ForbiddenError& e) {
    return {403, body(e.code(), e.what())};
  } catch (const ConflictError& e) {
    return {409, body(e.code(), e.what())};
  } catch (const TooLargeError& e) {
    return {413, body(e.code(), e.what())};
  } catch (const InputError& e) {  // includes ConfigError
    return {400, body(e.code(), e.what())};
  } catch (const NotFoundError& e) {
    return {404, body(e.code(), e.what())};
  } catch (const CancelledError& e) {
    return {409, body(e.code(), e.what())};
  } catch (const CorruptError& e) {
    return {500, body(e.code(), e.what())};
  } catch (const Error& e) {
    return {e.code() == "unavailable" ? 503 : 500, body(e.code(), e.what())};
  } catch (const json::exception& e) {
    return {400, body("invalid_json", std::string("request body: ") + e.what())};
  } catch (const std::exception& e) {
    spdlog::error("internal error: {}", e.what());
    return {500, body("internal", e.what())};
  } catch (...) {
    return {500, body("internal", "unknown error")};
  }
}

namespace {

void send_json(httplib::Response& res, const json& j, int status = 200) {
  res.status = status;
  res.set_content(j.dump(2) + "\n", "application/json");
}

// Reads a JSON body of at most `limit` bytes; malformed JSON is a 400 naming the position.
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

std::optional<uint64_t> header_number(const httplib::Request& req, const char* name) {
  if (!req.has_header(name)) return std::nullopt;
  try {
    return std::stoull(req.get_header_value(name));
  } catch (const std::exception&) {
    throw InputError(std::string(name) + ": not a number");
  }
}

// A single "bytes=a-b" range that starts past the end cannot be satisfied (RFC 9110 15.5.17).
bool range_unsatisfiable(const httplib::Request& req, uint64_t size) {
  if (req.ranges.size() != 1) return false;
  const auto [first, last] = req.ranges.front();
  if (first >= 0) return uint64_t(first) >= size || (last >= 0 && last < first);
  return last == 0 || size == 0;  // suffix range "-N"
}

// Query of a preview: scene=sphere|plane, light=T,P (camera frame, degrees), env=1, size=N.
PreviewOptions preview_query(const httplib::Request& req) {
  PreviewOptions o;
  if (req.has_param("scene")) o.scene = parse_preview_scene(req.get_param_value("scene"));
  auto number = [&](const char* key, const std::string& text) {
    size_t used = 0;
    double v = 0;
    try {
      v = std::stod(text, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used == 0 || used != text.size()) throw InputError(std::string(key) + ": '" + text + "' is not a number");
    return v;
  };
  if (req.has_param("size")) o.size = int(std::clamp(number("size", req.get_param_value("size")), -1.0, 1e6));
  if (req.has_param("light")) {
    const std::string l = req.get_param_value("light");
    const auto comma = l.find(',');
    if (comma == std::string::npos) throw InputError("light: '" + l + "' is not THETA,PHI in degrees");
    o.lights = {{{number("light", l.substr(0, comma)), number("light", l.substr(comma + 1))}, 1.0}};
  }
  if (req.has_param("env") && req.get_param_value("env") != "0") o.lights = preview_environment();
  return o;
}

std::string sse_event(const std::string& event, const json& data) {
  return "event: " + event + "\ndata: " + data.dump() + "\n\n";
}

}  // namespace

HttpServer::HttpServer(Service& service, HttpOptions options)
    : service_(service), options_(std::move(options)), server_(std::make_unique<httplib::Server>()) {
  const int threads = options_.threads;
  server_->new_task_queue = [threads] { return new httplib::ThreadPool(size_t(threads)); };
  server_->set_payload_max_length(size_t(service_.config().max_upload_bytes) + 1);
  server_->set_read_timeout(60);
  server_->set_write_timeout(60);
  install_routes();
}

HttpServer::~HttpServer() { stop(); }

int HttpServer::bind(const std::string& host, int port) {
  const bool ok = port == 0 ? (port = server_->bind_to_any_port(host)) > 0 : server_->bind_to_port(host, port);
  if (!ok) throw Error("bind", "cannot listen on " + host + ":" + std::to_string(port));
  spdlog::info("listening on http://{}:{}", host, port);
  return port;
}

void HttpServer::run() { server_->listen_after_bind(); }

void HttpServer::run_in_background() {
  thread_ = std::thread([this] { run(); });
  while (!server_->is_running()) std::this_thread::sleep_for(std::chrono::milliseconds(1));
}

void HttpServer::stop() {
  stopping_ = true;
  server_->stop();
  if (thread_.joinable()) thread_.join();
}

void HttpServer::install_routes() {
  auto& s = *server_;
  Service& svc = service_;

  s.set_exception_handler([](const httplib::Request&, httplib::Response& res, std::exception_ptr ep) {
    auto [status, body] = error_response(ep);
    res.status = status;
    res.set_content(body, "application/json");
  });
  // Errors raised by httplib itself (unknown route, unparsable Range, payload limit) get the same shape.
  s.set_error_handler([](const httplib::Request&, httplib::Response& res) {
    if (!res.body.empty()) return;
    const std::string code = res.status == 404 ? "not_found" : res.status == 413 ? "too_large"
                           : res.status == 416 ? "range_not_satisfiable" : "http_" + std::to_string(res.status);
    res.set_content(json{{"error", {{"code", code}, {"message", "HTTP status " + std::to_string(res.status)}}}}.dump(),
                    "application/json");
  });
  s.set_pre_routing_handler([this](const httplib::Request& req, httplib::Response& res) {
    if (options_.token.empty() || req.path == "/healthz" || req.path == "/v1/healthz")
      return httplib::Server::HandlerResponse::Unhandled;
    if (req.get_header_value("Authorization") == "Bearer " + options_.token)
      return httplib::Server::HandlerResponse::Unhandled;
    auto [status, body] = error_response(std::make_exception_ptr(
        UnauthorizedError("a valid 'Authorization: Bearer <token>' header is required")));
    res.status = status;
    res.set_header("WWW-Authenticate", "Bearer");
    res.set_header("Connection", "close");
    res.set_content(body, "application/json");
    return httplib::Server::HandlerResponse::Handled;
  });

  auto healthz = [](const httplib::Request&, httplib::Response& res) { send_json(res, {{"status", "ok"}}); };
  s.Get("/healthz", healthz);
  s.Get("/v1/healthz", healthz);
  s.Get("/metrics", [&svc](const httplib::Request&, httplib::Response& res) {
    res.set_content(svc.metrics(), "text/plain; version=0.0.4");
  });
  s.Get("/v1/metrics", [&svc](const httplib::Request&, httplib::Response& res) {
    res.set_content(svc.metrics(), "text/plain; version=0.0.4");
  });

  // ---- jobs
  s.Post("/v1/jobs", [this, &svc](const httplib::Request&, httplib::Response& res, const httplib::ContentReader& reader) {
    send_json(res, svc.submit(read_json_body(reader, options_.max_request_bytes)), 202);
  });
  s.Get("/v1/jobs", [&svc](const httplib::Request&, httplib::Response& res) { send_json(res, {{"jobs", svc.jobs()}}); });
  s.Get(R"(/v1/jobs/([^/]+))", [&svc](const httplib::Request& req, httplib::Response& res) {
    send_json(res, svc.job(req.matches[1]));
  });
  s.Delete(R"(/v1/jobs/([^/]+))", [&svc](const httplib::Request& req, httplib::Response& res) {
    send_json(res, svc.cancel(req.matches[1]), 202);
  });
  s.Get(R"(/v1/jobs/([^/]+)/events)", [this, &svc](const httplib::Request& req, httplib::Response& res) {
    const std::string id = req.matches[1];
    svc.job(id);  // 404 before the stream starts
    struct Stream {
      std::string last;
      uint64_t revision = 0;
      std::chrono::steady_clock::time_point last_write = std::chrono::steady_clock::now();
    };
    auto state = std::make_shared<Stream>();
    res.set_header("Cache-Control", "no-cache");
    res.set_chunked_content_provider("text/event-stream", [this, &svc, id, state](size_t, httplib::DataSink& sink) {
      for (;;) {
        if (stopping_ || svc.stopping()) return false;
        const uint64_t seen = svc.revision();
        const json job = svc.job(id);
        // Elapsed time and ETA tick by themselves; an event is due when anything else changed.
        json key = job;
        key.erase("elapsed_s");
        key.erase("eta_s");
        const std::string text = key.dump();
        if (text != state->last) {
          state->last = text;
          const bool final = is_final(job["state"].get<JobState>());
          const std::string e = sse_event(final ? "end" : "progress", job);
          if (!sink.write(e.data(), e.size())) return false;
          state->last_write = std::chrono::steady_clock::now();
          if (final) sink.done();
          return true;  // httplib flushes and calls again
        }
        if (std::chrono::steady_clock::now() - state->last_write > std::chrono::seconds(15)) {
          static const std::string ping = ": keep-alive\n\n";
          if (!sink.write(ping.data(), ping.size())) return false;
          state->last_write = std::chrono::steady_clock::now();
          return true;
        }
        svc.wait_for_change(seen, std::chrono::milliseconds(500));
      }
    });
  });

  // ---- uploads
  s.Put(R"(/v1/uploads/([^/]+))", [&svc](const httplib::Request& req, httplib::Response& res,
                                         const httplib::ContentReader& reader) {
    auto sink = svc.begin_upload(req.matches[1], header_number(req, "Content-Length"));
    // Past the limit the rest of a modest body is drained, so that the client reads our 413
    // instead of a connection reset; a huge one is cut off.
    uint64_t drained = 0;
    const bool complete = reader([&](const char* data, size_t n) {
      if (!sink->too_large() && sink->write(data, n)) return true;
      if (!sink->too_large()) return false;
      drained += n;
      return drained < (uint64_t(64) << 20);
    });
    if (sink->too_large()) {
      res.set_header("Connection", "close");
      throw TooLargeError("upload exceeds the limit of " + std::to_string(svc.config().max_upload_bytes) + " bytes");
    }
    if (!complete) throw InputError("upload interrupted before the end of the body", "incomplete_upload");
    send_json(res, sink->finish(req.get_header_value("X-Sha256")), 201);
  });
  s.Get(R"(/v1/uploads/([^/]+))", [&svc](const httplib::Request& req, httplib::Response& res) {
    send_json(res, svc.upload(req.matches[1]));
  });

  // ---- databases
  s.Get("/v1/databases", [&svc](const httplib::Request&, httplib::Response& res) {
    send_json(res, {{"databases", svc.databases()}});
  });
  s.Get(R"(/v1/databases/([^/]+))", [&svc](const httplib::Request& req, httplib::Response& res) {
    send_json(res, svc.database(req.matches[1]));
  });
  s.Get(R"(/v1/databases/([^/]+)/materials/([^/]+)/preview\.png)", [&svc](const httplib::Request& req, httplib::Response& res) {
    const auto png = svc.preview(req.matches[1], req.matches[2], preview_query(req));
    res.set_content(std::string(png.begin(), png.end()), "image/png");
  });
  s.Get(R"(/v1/databases/([^/]+)/content)", [&svc](const httplib::Request& req, httplib::Response& res) {
    std::optional<int64_t> version;
    if (req.has_param("version")) {
      const std::string v = req.get_param_value("version");
      size_t used = 0;
      try {
        version = std::stoll(v, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used == 0 || used != v.size() || *version < 1) throw InputError("version: '" + v + "' is not a version number");
    }
    const ContentInfo c = svc.content(req.matches[1], version);
    const std::string etag = "\"" + c.sha256 + "\"";
    res.set_header("ETag", etag);
    res.set_header("X-Content-Sha256", c.sha256);
    res.set_header("X-Database-Version", std::to_string(c.version));
    res.set_header("Accept-Ranges", "bytes");
    if (req.get_header_value("If-None-Match") == etag) {
      res.status = 304;
      return;
    }
    if (range_unsatisfiable(req, c.size)) {
      res.status = 416;
      res.set_header("Content-Range", "bytes */" + std::to_string(c.size));
      res.set_content(json{{"error", {{"code", "range_not_satisfiable"},
                                      {"message", "range is outside the " + std::to_string(c.size) + "-byte content"}}}}
                          .dump(),
                      "application/json");
      return;
    }
    auto file = std::make_shared<std::ifstream>(c.path, std::ios::binary);
    if (!*file) throw Error("io", "cannot open the file of " + c.database + " version " + std::to_string(c.version));
    // httplib applies the request's Range to this provider (206 with Content-Range).
    res.set_content_provider(
        size_t(c.size), "application/octet-stream", [file, &svc](size_t offset, size_t length, httplib::DataSink& sink) {
          std::vector<char> buffer(std::min<size_t>(length, 1 << 16));
          file->seekg(std::streamoff(offset));
          file->read(buffer.data(), std::streamsize(buffer.size()));
          const size_t got = size_t(file->gcount());
          if (got == 0) return false;
          if (!sink.write(buffer.data(), got)) return false;
          svc.count_bytes_served(got);
          return true;
        });
  });
}

}  // namespace btfvq::server
