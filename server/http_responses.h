#pragma once
// Writing responses: JSON, errors (in the shape of http_errors.h), server-sent events and files
// with byte ranges.
#include <httplib.h>
#include <nlohmann/json.hpp>

#include <atomic>
#include <exception>
#include <functional>
#include <optional>
#include <string>

#include "server/service.h"
#include "server/viewer_files.h"

namespace btfvq::server {

void send_json(httplib::Response& res, const nlohmann::json& body, int status = 200);
void send_error(httplib::Response& res, std::exception_ptr error);

// One event of a text/event-stream.
struct ServerEvent {
  std::string name;
  nlohmann::json data;
  bool last = false;  // the stream ends after it
};
// The event due now, if any; asked again whenever the service changed.
using EventSource = std::function<std::optional<ServerEvent>()>;

// Streams the events of `next` until the last one, the client leaving, or either the service or
// the HTTP server (`http_stopping`) stopping. A comment line every 15 s of silence keeps proxies
// from closing an idle stream.
void send_event_stream(httplib::Response& res, Service& service, const std::atomic<bool>& http_stopping,
                       EventSource next);

// The events of one job (GET /v1/jobs/{id}/events): "progress" whenever the job changed, "end"
// once it is final. Throws NotFoundError at once, before a stream starts, for an unknown job.
EventSource job_events(Service& service, const std::string& id);

// A published database version (GET /v1/databases/{name}/content) with its ETag (the sha256),
// X-Content-Sha256 and X-Database-Version: 304 for a matching If-None-Match, 416 for a range that
// starts past the end, else the file, to which httplib applies a Range (206). The bytes sent count
// in the service's metrics.
void send_content(const httplib::Request& req, httplib::Response& res, Service& service, const ContentInfo& content);

// One of the viewer's files. no-cache: a browser revalidates, so a new server build is seen at once.
void send_viewer_file(httplib::Response& res, const ViewerFile& file);

}  // namespace btfvq::server
