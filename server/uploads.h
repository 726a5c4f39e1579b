#pragma once
// Uploads (PUT /v1/uploads/{id}): streamed to disk and hashed while they arrive, recorded in the
// store once complete. The store lists only complete uploads; the ones still arriving live here.
// An upload is sent either whole (one PUT) or in pieces (PUTs with Content-Range, resumable: the
// pieces so far stay in partial-uploads/ until the last one arrives, or until the upload has been
// left alone for upload_abandon_after_s).
#include <nlohmann/json.hpp>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "pipeline/util/atomic_file.h"
#include "pipeline/util/sha256.h"
#include "server/data_dir.h"
#include "server/store.h"

namespace btfvq::server {

class Uploads;

// Content-Range: bytes FIRST-LAST/TOTAL of one piece (inclusive, as HTTP counts).
struct ContentRange {
  uint64_t first = 0, last = 0, total = 0;
  uint64_t length() const { return last - first + 1; }
};

// What a PUT says about its body.
struct UploadRequest {
  std::optional<uint64_t> declared_size;  // Content-Length
  std::optional<ContentRange> range;      // a piece of a resumable upload
  std::string sha256;                     // X-Sha256, lower-case hex; may be empty
};

// One request body being streamed to disk: a whole upload to the temporary of an AtomicFile (so that
// one destroyed without finish(), by a broken connection or a bad checksum, leaves nothing behind),
// or a piece appended to its upload's .part (whose bytes stay for the next piece, whatever happens).
class UploadSink {
 public:
  ~UploadSink();
  UploadSink(const UploadSink&) = delete;
  UploadSink& operator=(const UploadSink&) = delete;
  // Appends bytes; returns false (and sets too_large()) once the size limit would be exceeded.
  // Throws NoSpaceError or Error("io") when the disk refuses them.
  bool write(const char* data, size_t size);
  bool too_large() const { return too_large_; }
  uint64_t limit() const { return limit_; }
  // A whole upload: verifies X-Sha256 (if given), commits the file and records the upload.
  // A piece: makes it durable; the last one verifies the whole file and records the upload (a
  // mismatch removes the partial upload). Returns the upload's state ("complete" or "partial").
  nlohmann::json finish();

 private:
  friend class Uploads;
  UploadSink(Uploads& uploads, std::string id, const UploadRequest& request,
             std::shared_ptr<std::atomic<uint64_t>> progress);
  nlohmann::json finish_whole();
  nlohmann::json finish_piece();
  void close_file();

  Uploads& uploads_;
  std::string id_;
  UploadRequest request_;
  std::optional<AtomicFile> file_;  // whole uploads; reset before the id is released: a free id has no temporary
  std::string path_;                // where the bytes go
  int fd_ = -1;
  Sha256 hash_;
  uint64_t size_ = 0, limit_ = 0;
  bool too_large_ = false, done_ = false;
  std::shared_ptr<std::atomic<uint64_t>> progress_;
};

class Uploads {
 public:
  Uploads(Store& store, DataDir data, uint64_t max_bytes);

  // A whole upload, or with request.range a piece of a resumable one. Checks everything that can be
  // checked before a byte is read: the id, the size limit (Content-Length or the range's total),
  // that a piece starts where the upload stands (UploadOffsetError otherwise) and that the first
  // piece names the file's sha256.
  std::unique_ptr<UploadSink> begin(const std::string& id, const UploadRequest& request);
  // A complete upload's record; "uploading" with the bytes so far for a whole upload arriving;
  // "partial" with `received` and `total` for a resumable one.
  nlohmann::json info(const std::string& id);
  // At startup: removes what a crash left in uploads/ (temporaries, files never recorded) and in
  // partial-uploads/ (a .part or .json without its pair, temporaries, partials of complete uploads).
  void remove_unlisted();
  // Removes the resumable uploads that received nothing for `age` (one arriving now is kept);
  // returns how many.
  size_t remove_abandoned(std::chrono::duration<double> age);
  uint64_t bytes_received() const { return bytes_received_; }

 private:
  friend class UploadSink;
  std::unique_ptr<UploadSink> begin_piece(const std::string& id, const UploadRequest& request);
  std::shared_ptr<std::atomic<uint64_t>> reserve(const std::string& id);
  void release(const std::string& id);
  void remove_partial(const std::string& id);
  std::optional<nlohmann::json> partial_meta(const std::string& id);  // null unless .part and .json both exist

  Store& store_;
  DataDir data_;
  uint64_t max_bytes_;
  std::mutex mutex_;
  std::map<std::string, std::shared_ptr<std::atomic<uint64_t>>> arriving_;  // bytes so far, by id
  std::atomic<uint64_t> bytes_received_{0};
};

}  // namespace btfvq::server
