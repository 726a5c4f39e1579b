#pragma once
// Uploads (PUT /v1/uploads/{id}): streamed to disk and hashed while they arrive, recorded in the
// store once complete. The store lists only complete uploads; the ones still arriving live here.
#include <nlohmann/json.hpp>

#include <atomic>
#include <cstdint>
#include <fstream>
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

// One upload being streamed to the temporary of an AtomicFile, so that an upload destroyed
// without finish() (a broken connection, a bad checksum) leaves nothing behind.
class UploadSink {
 public:
  ~UploadSink();
  // Appends bytes; returns false (and sets too_large()) once the size limit would be exceeded.
  bool write(const char* data, size_t size);
  bool too_large() const { return too_large_; }
  uint64_t limit() const;
  // Verifies `expected_sha256` (if not empty), commits the file and records the upload.
  nlohmann::json finish(const std::string& expected_sha256);

 private:
  friend class Uploads;
  UploadSink(Uploads& uploads, std::string id, std::shared_ptr<std::atomic<uint64_t>> progress);
  Uploads& uploads_;
  std::string id_;
  std::optional<AtomicFile> file_;  // reset before the id is released: a free id has no temporary
  std::ofstream out_;
  Sha256 hash_;
  uint64_t size_ = 0;
  bool too_large_ = false, done_ = false;
  std::shared_ptr<std::atomic<uint64_t>> progress_;
};

class Uploads {
 public:
  Uploads(Store& store, DataDir data, uint64_t max_bytes);

  // `declared_size` (Content-Length) lets an oversized upload fail before any byte is read.
  std::unique_ptr<UploadSink> begin(const std::string& id, std::optional<uint64_t> declared_size);
  nlohmann::json info(const std::string& id);
  // At startup: removes what a crash left in uploads/ (temporaries, files never recorded).
  void remove_unlisted();
  uint64_t bytes_received() const { return bytes_received_; }

 private:
  friend class UploadSink;
  std::shared_ptr<std::atomic<uint64_t>> reserve(const std::string& id);
  void release(const std::string& id);

  Store& store_;
  DataDir data_;
  uint64_t max_bytes_;
  std::mutex mutex_;
  std::map<std::string, std::shared_ptr<std::atomic<uint64_t>>> arriving_;  // bytes so far, by id
  std::atomic<uint64_t> bytes_received_{0};
};

}  // namespace btfvq::server
