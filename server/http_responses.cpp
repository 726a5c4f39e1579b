#include "server/http_responses.h"

#include <chrono>
#include <fstream>
#include <memory>
#include <vector>

#include <btfvq/error.h>
#include "server/errors.h"
#include "server/http_errors.h"

namespace btfvq::server {
using nlohmann::json;
using Clock = std::chrono::steady_clock;

namespace {

constexpr auto kKeepAlive = std::chrono::seconds(15);
constexpr auto kPoll = std::chrono::milliseconds(500);  // how long a stream waits for a change

// A single "bytes=a-b" range that starts past the end cannot be satisfied (RFC 9110 15.5.17).
bool range_unsatisfiable(const httplib::Request& req, uint64_t size) {
  if (req.ranges.size() != 1) return false;
  const auto [first, last] = req.ranges.front();
  if (first >= 0) return uint64_t(first) >= size || (last >= 0 && last < first);
  return last == 0 || size == 0;  // suffix range "-N"
}

// A file with a strong ETag and byte ranges, read in pieces as httplib asks for them (it applies
// the Range). `on_sent` counts the bytes sent.
void send_file(const httplib::Request& req, httplib::Response& res, const ContentInfo& content,
               std::function<void(size_t)> on_sent) {
  const uint64_t size = content.size;
  const std::string etag = "\"" + content.sha256 + "\"";
  res.set_header("ETag", etag);
  res.set_header("Accept-Ranges", "bytes");
  if (req.get_header_value("If-None-Match") == etag) {
    res.status = 304;
    return;
  }
  if (range_unsatisfiable(req, size)) {
    res.set_header("Content-Range", "bytes */" + std::to_string(size));
    send_error(res, std::make_exception_ptr(
                        RangeNotSatisfiableError("range is outside the " + std::to_string(size) + "-byte content")));
    return;
  }
  auto file = std::make_shared<std::ifstream>(content.path, std::ios::binary);
  if (!*file)
    throw Error("io", "cannot open the file of " + content.database + " version " + std::to_string(content.version));
  res.set_content_provider(size_t(size), "application/octet-stream",
                           [file, on_sent](size_t offset, size_t length, httplib::DataSink& sink) {
                             std::vector<char> buffer(std::min<size_t>(length, 1 << 16));
                             file->seekg(std::streamoff(offset));
                             file->read(buffer.data(), std::streamsize(buffer.size()));
                             const size_t got = size_t(file->gcount());
                             if (got == 0) return false;
                             // Counted before the write: a client that has the bytes must see them
                             // in /metrics (after the write, the count raced the client's next request).
                             on_sent(got);
                             return sink.write(buffer.data(), got);
                           });
}

}  // namespace

void send_json(httplib::Response& res, const json& body, int status) {
  res.status = status;
  res.set_content(body.dump(2, ' ', false, json::error_handler_t::replace) + "\n", "application/json");
}

void send_error(httplib::Response& res, std::exception_ptr error) {
  auto [status, body] = error_response(error);
  res.status = status;
  res.set_content(body, "application/json");
}

void send_event_stream(httplib::Response& res, Service& service, const std::atomic<bool>& http_stopping,
                       EventSource next) {
  struct Stream {
    EventSource next;
    Clock::time_point last_write = Clock::now();
    bool write(httplib::DataSink& sink, const std::string& text) {
      last_write = Clock::now();
      return sink.write(text.data(), text.size());
    }
  };
  auto stream = std::make_shared<Stream>(Stream{std::move(next)});
  res.set_header("Cache-Control", "no-cache");
  res.set_chunked_content_provider(
      "text/event-stream", [&service, &http_stopping, stream](size_t, httplib::DataSink& sink) {
        for (;;) {
          if (http_stopping || service.stopping()) return false;
          const uint64_t seen = service.revision();
          if (auto event = stream->next()) {
            if (!stream->write(sink, "event: " + event->name + "\ndata: " + event->data.dump(-1, ' ', false, json::error_handler_t::replace) + "\n\n")) return false;
            if (event->last) sink.done();
            return true;  // httplib flushes and calls again
          }
          if (Clock::now() - stream->last_write > kKeepAlive) return stream->write(sink, ": keep-alive\n\n");
          service.wait_for_change(seen, kPoll);
        }
      });
}

EventSource job_events(Service& service, const std::string& id) {
  service.job(id);
  return [&service, id, last = std::string()]() mutable -> std::optional<ServerEvent> {
    json job = service.job(id);
    // Elapsed time and ETA tick by themselves: they alone are no change.
    json key = job;
    key.erase("elapsed_s");
    key.erase("eta_s");
    std::string text = key.dump(-1, ' ', false, json::error_handler_t::replace);
    if (text == last) return std::nullopt;
    last = std::move(text);
    const bool final = is_final(job["state"].get<JobState>());
    return ServerEvent{final ? "end" : "progress", std::move(job), final};
  };
}

void send_viewer_file(httplib::Response& res, const ViewerFile& file) {
  res.set_header("Cache-Control", "no-cache");
  res.set_content(file.body, file.content_type);
}

void send_content(const httplib::Request& req, httplib::Response& res, Service& service, const ContentInfo& c) {
  res.set_header("X-Content-Sha256", c.sha256);
  res.set_header("X-Database-Version", std::to_string(c.version));
  send_file(req, res, c, [&service](size_t n) { service.count_bytes_served(n); });
}

}  // namespace btfvq::server
