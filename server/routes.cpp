// REST routes (docs/api.md): each handler is a line or two over the Service. Everything that can go
// wrong is thrown as a btfvq::Error and reaches the client through error_response() (http_errors.h).
#include <httplib.h>
#include <spdlog/spdlog.h>

#include <chrono>

#include "server/errors.h"
#include "server/http_errors.h"
#include "server/http_requests.h"
#include "server/http_responses.h"
#include "server/http_server.h"
#include "server/metrics_text.h"
#include "server/viewer_files.h"

namespace btfvq::server {
using nlohmann::json;
using httplib::ContentReader;
using httplib::Request;
using httplib::Response;

HttpServer::HttpServer(Service& service, HttpOptions options)
    : service_(service), options_(std::move(options)), server_(make_limited_server(options_.connections, connections_)) {
  server_->set_payload_max_length(size_t(service_.config().max_upload_bytes) + 1);
  install_handlers();
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

void HttpServer::install_handlers() {
  auto& s = *server_;
  s.set_exception_handler([](const Request&, Response& res, std::exception_ptr e) { send_error(res, e); });
  // Errors that httplib raises itself (unknown route, unparsable Range, payload limit) get the same shape.
  s.set_error_handler([](const Request&, Response& res) {
    if (res.body.empty())
      res.set_content(error_body(code_of_status(res.status), "HTTP status " + std::to_string(res.status)),
                      "application/json");
  });
  s.set_pre_routing_handler([this](const Request& req, Response& res) {
    const bool open = options_.token.empty() || req.path == "/healthz" || req.path == "/v1/healthz";
    if (open || req.get_header_value("Authorization") == "Bearer " + options_.token)
      return httplib::Server::HandlerResponse::Unhandled;
    res.set_header("WWW-Authenticate", "Bearer");
    res.set_header("Connection", "close");
    send_error(res, std::make_exception_ptr(
                        UnauthorizedError("a valid 'Authorization: Bearer <token>' header is required")));
    return httplib::Server::HandlerResponse::Handled;
  });
}

void HttpServer::install_routes() {
  auto& s = *server_;
  Service& svc = service_;

  auto healthz = [](const Request&, Response& res) { send_json(res, {{"status", "ok"}}); };
  s.Get("/healthz", healthz);
  s.Get("/v1/healthz", healthz);
  auto metrics = [this, &svc](const Request&, Response& res) {
    res.set_content(svc.metrics() + connection_metrics_text(connections_), "text/plain; version=0.0.4");
  };
  s.Get("/metrics", metrics);
  s.Get("/v1/metrics", metrics);

  // ---- jobs
  s.Post("/v1/jobs", [this, &svc](const Request&, Response& res, const ContentReader& reader) {
    send_json(res, svc.submit(read_json_body(reader, options_.max_request_bytes)), 202);
  });
  s.Get("/v1/jobs", [&svc](const Request&, Response& res) { send_json(res, {{"jobs", svc.jobs()}}); });
  s.Get(R"(/v1/jobs/([^/]+))", [&svc](const Request& req, Response& res) { send_json(res, svc.job(req.matches[1])); });
  s.Delete(R"(/v1/jobs/([^/]+))", [&svc](const Request& req, Response& res) {
    send_json(res, svc.cancel(req.matches[1]), 202);
  });
  s.Get(R"(/v1/jobs/([^/]+)/events)", [this, &svc](const Request& req, Response& res) {
    send_event_stream(res, svc, stopping_, job_events(svc, req.matches[1]));
  });

  // ---- uploads
  s.Put(R"(/v1/uploads/([^/]+))", [&svc](const Request& req, Response& res, const ContentReader& reader) {
    const json reply =
        receive_upload(req, reader, res, [&] { return svc.begin_upload(req.matches[1], upload_request(req)); });
    send_json(res, reply, reply["state"] == "complete" ? 201 : 200);
  });
  s.Get(R"(/v1/uploads/([^/]+))", [&svc](const Request& req, Response& res) {
    send_json(res, svc.upload(req.matches[1]));
  });

  // ---- databases
  s.Get("/v1/databases", [&svc](const Request&, Response& res) { send_json(res, {{"databases", svc.databases()}}); });
  s.Get(R"(/v1/databases/([^/]+))", [&svc](const Request& req, Response& res) {
    send_json(res, svc.database(req.matches[1]));
  });
  s.Get(R"(/v1/databases/([^/]+)/materials/([^/]+)/preview\.png)", [&svc](const Request& req, Response& res) {
    const auto png = svc.preview(req.matches[1], req.matches[2], preview_query(req));
    res.set_content(std::string(png.begin(), png.end()), "image/png");
  });
  s.Get(R"(/v1/databases/([^/]+)/content)", [&svc](const Request& req, Response& res) {
    send_content(req, res, svc, svc.content(req.matches[1], version_query(req)));
  });

  // ---- the browser viewer (docs/viewer.md): static files; the page reads the API above itself.
  s.Get("/viewer", [](const Request&, Response& res) { res.set_redirect("/viewer/", 301); });
  auto page = [](const Request&, Response& res) { send_viewer_file(res, viewer_page()); };
  s.Get("/viewer/", page);
  s.Get(R"(/viewer/static/([^/]+))", [](const Request& req, Response& res) {
    send_viewer_file(res, viewer_file(req.matches[1]));
  });
  s.Get(R"(/viewer/([^/]+)/([^/]+))", page);
}

}  // namespace btfvq::server
