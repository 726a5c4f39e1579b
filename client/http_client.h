#pragma once
// The client side of the REST API (docs/api.md), shared by the remote subcommands. HTTP errors
// come back as the typed btfvq errors (400 -> InputError, 404 -> NotFoundError, ...) carrying the
// server's message, so main.cpp maps them to exit codes like local failures.
#include <nlohmann/json.hpp>

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "pipeline/util/args.h"

namespace httplib {
class Client;
}

namespace btfvq::cli {

struct Remote {
  std::string url;    // http://host:port
  std::string token;  // empty: no Authorization header
};

// --server / BTFVQ_SERVER and --token / BTFVQ_TOKEN.
Remote remote_from(const Args& args);
// The options remote_from reads, then a remote command's own.
std::vector<Option> remote_options(std::vector<Option> own = {});

using ByteProgress = std::function<void(uint64_t done, uint64_t total)>;

struct DownloadResult {
  uint64_t size = 0;
  std::string sha256;
  int64_t version = 0;
  uint64_t resumed_from = 0;  // bytes already present in FILE.part
};

class HttpClient {
 public:
  explicit HttpClient(Remote remote);
  ~HttpClient();

  nlohmann::json get_json(const std::string& path);
  nlohmann::json post_json(const std::string& path, const nlohmann::json& body);
  nlohmann::json delete_json(const std::string& path);
  // Streams a file as the body of PUT `path` with an X-Sha256 header.
  nlohmann::json put_file(const std::string& path, const std::string& file, const std::string& sha256,
                          const ByteProgress& progress);
  // Follows a server-sent event stream; `on_event(event, data)` returns false to stop early.
  // Returns when the server ends the stream (or on_event said stop); throws on HTTP errors.
  void events(const std::string& path, const std::function<bool(const std::string&, const nlohmann::json&)>& on_event);

  // Downloads database `name` to `out`: writes `out`.part (and `out`.part.json, which pins the
  // version being fetched), resumes an interrupted download with a Range request, verifies the
  // sha256 against X-Content-Sha256, and renames into place only when verified. A resume that
  // fails verification starts over once. Throws CorruptError if the fresh copy does not verify.
  DownloadResult download_database(const std::string& name, const std::string& out, std::optional<int64_t> version,
                                   const ByteProgress& progress);

 private:
  DownloadResult fetch(const std::string& name, const std::string& out, std::optional<int64_t> version,
                       const ByteProgress& progress);
  std::unique_ptr<httplib::Client> client_;
  Remote remote_;
};

// One line about a job's progress: "phase 2 (phase2) 1234/5000 texels, P4 812, ETA 35 s".
std::string describe_progress(const nlohmann::json& job);

// Throws the btfvq error that matches an HTTP status and an error body {"error": {code, message}}.
[[noreturn]] void throw_http_error(int status, const std::string& body);

}  // namespace btfvq::cli
