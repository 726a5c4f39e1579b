#pragma once
// The client side of the REST API (docs/api.md), shared by the remote subcommands. HTTP errors
// come back as the typed btfvq errors (400 -> InputError, 404 -> NotFoundError, ...) carrying the
// server's message, so main.cpp maps them to exit codes like local failures.
#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
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
  uint64_t transferred = 0;   // body bytes received from the server by this call
  int64_t delta_from = 0;     // the version of the local file that was brought up to date (0: a full download)
  std::string fallback;       // why a delta download was not possible (empty: it was, or none was tried)
};

// How `btfvq submit --upload` sends a file: in pieces (PUT with Content-Range), each retried after a
// network error or a 5xx with a growing pause, continuing from what the server says it has.
struct UploadOptions {
  uint64_t piece_bytes = uint64_t(8) << 20;
  int max_retries = 8;                                 // in a row, without a piece getting through
  std::chrono::milliseconds first_pause{500};          // doubled after each retry, up to max_pause
  std::chrono::milliseconds max_pause{8000};
};

struct UploadResult {
  nlohmann::json record;      // the server's record of the complete upload
  uint64_t resumed_from = 0;  // bytes the server already had when the upload began
  uint64_t bytes_sent = 0;    // body bytes sent, those sent again after a failure included
  int retries = 0;
  bool existed = false;       // the server had the complete upload already: nothing was sent
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
  // Uploads `file` (whose sha256 is `sha256`) as upload `id` in pieces: asks the server where a
  // previous attempt got to (GET /v1/uploads/{id}) and continues there; a complete upload of the
  // same sha256 is used as it is. Throws when a piece is refused (4xx) or the retries run out.
  UploadResult upload_file(const std::string& id, const std::string& file, const std::string& sha256,
                           const ByteProgress& progress, const UploadOptions& options = {});
  // Follows a server-sent event stream; `on_event(event, data)` returns false to stop early.
  // Returns when the server ends the stream (or on_event said stop); throws on HTTP errors.
  void events(const std::string& path, const std::function<bool(const std::string&, const nlohmann::json&)>& on_event);

  // Downloads database `name` to `out`: writes `out`.part (and `out`.part.json, which pins the
  // version being fetched), resumes an interrupted download with a Range request, verifies the
  // sha256 against X-Content-Sha256, and renames into place only when verified. A resume that
  // fails verification starts over once. Throws CorruptError if the fresh copy does not verify.
  // When `out` exists already and is a published version of the database (its sha256 is one the
  // server lists), only the new head and the sections added since are fetched (docs/api.md "Delta
  // downloads"); anything unexpected there falls back to a full download.
  DownloadResult download_database(const std::string& name, const std::string& out, std::optional<int64_t> version,
                                   const ByteProgress& progress);

 private:
  DownloadResult fetch(const std::string& name, const std::string& out, std::optional<int64_t> version,
                       const ByteProgress& progress);
  // The delta download; throws (anything) when it is not possible, and the caller downloads fully.
  DownloadResult delta(const std::string& name, const std::string& out, std::optional<int64_t> version,
                       const ByteProgress& progress);
  std::unique_ptr<httplib::Client> client_;
  Remote remote_;
};

// One line about a job's progress: "phase 2 (phase2) 1234/5000 texels, P4 812, ETA 35 s".
std::string describe_progress(const nlohmann::json& job);

// Throws the btfvq error that matches an HTTP status and an error body {"error": {code, message}}.
[[noreturn]] void throw_http_error(int status, const std::string& body);

}  // namespace btfvq::cli
