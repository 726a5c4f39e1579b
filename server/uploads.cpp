#include "server/uploads.h"

#include <spdlog/spdlog.h>

#include <btfvq/error.h>
#include "server/errors.h"
#include "server/job_request.h"

namespace btfvq::server {
namespace fs = std::filesystem;
using nlohmann::json;

UploadSink::UploadSink(Uploads& uploads, std::string id, std::shared_ptr<std::atomic<uint64_t>> progress)
    : uploads_(uploads),
      id_(std::move(id)),
      file_(std::in_place, uploads_.data_.upload(id_).string()),
      progress_(std::move(progress)) {
  out_.open(file_->temp_path(), std::ios::binary | std::ios::trunc);
  if (!out_) throw Error("io", "cannot create '" + file_->temp_path() + "'");
}

UploadSink::~UploadSink() {
  if (out_.is_open()) out_.close();
  file_.reset();
  if (!done_ && size_ > 0) spdlog::info("upload {} abandoned after {} bytes", id_, size_);
  uploads_.release(id_);
}

uint64_t UploadSink::limit() const { return uploads_.max_bytes_; }

bool UploadSink::write(const char* data, size_t size) {
  if (size_ + size > limit()) {
    too_large_ = true;
    return false;
  }
  out_.write(data, std::streamsize(size));
  hash_.update(data, size);
  size_ += size;
  *progress_ = size_;
  uploads_.bytes_received_ += size;
  return bool(out_);
}

json UploadSink::finish(const std::string& expected_sha256) {
  out_.close();
  if (!out_) throw Error("io", "cannot write upload '" + id_ + "'");
  const std::string sha = hash_.hex();
  if (!expected_sha256.empty() && expected_sha256 != sha)
    throw InputError("X-Sha256: the upload hashes to " + sha + ", not " + expected_sha256, "checksum_mismatch");
  file_->commit();
  uploads_.store_.insert_upload({id_, size_, sha, "complete", now_seconds()});
  done_ = true;
  spdlog::info("upload {} complete: {} bytes, sha256 {}", id_, size_, sha);
  return {{"id", id_}, {"size", size_}, {"sha256", sha}, {"state", "complete"}};
}

Uploads::Uploads(Store& store, DataDir data, uint64_t max_bytes)
    : store_(store), data_(std::move(data)), max_bytes_(max_bytes) {}

std::unique_ptr<UploadSink> Uploads::begin(const std::string& id, std::optional<uint64_t> declared_size) {
  if (!valid_name(id)) throw InputError("upload id '" + id + "': use 1-64 of [A-Za-z0-9._-]", "invalid_request");
  if (declared_size && *declared_size > max_bytes_)
    throw TooLargeError("upload of " + std::to_string(*declared_size) + " bytes exceeds the limit of " +
                        std::to_string(max_bytes_) + " bytes");
  auto progress = reserve(id);
  try {
    return std::unique_ptr<UploadSink>(new UploadSink(*this, id, std::move(progress)));
  } catch (...) {
    release(id);
    throw;
  }
}

std::shared_ptr<std::atomic<uint64_t>> Uploads::reserve(const std::string& id) {
  std::lock_guard lock(mutex_);
  if (arriving_.count(id)) throw ConflictError("upload '" + id + "' is in progress");
  if (store_.upload(id)) throw ConflictError("upload '" + id + "' exists already");
  return arriving_[id] = std::make_shared<std::atomic<uint64_t>>(0);
}

void Uploads::release(const std::string& id) {
  std::lock_guard lock(mutex_);
  arriving_.erase(id);
}

json Uploads::info(const std::string& id) {
  if (auto u = store_.upload(id))
    return {{"id", u->id}, {"size", u->size}, {"sha256", u->sha256}, {"state", u->state}, {"created", u->created}};
  std::lock_guard lock(mutex_);
  if (auto it = arriving_.find(id); it != arriving_.end())
    return {{"id", id}, {"size", it->second->load()}, {"state", "uploading"}};
  throw NotFoundError("no upload '" + id + "'");
}

void Uploads::remove_unlisted() {
  for (const auto& entry : fs::directory_iterator(data_.uploads())) {
    const bool complete =
        entry.path().extension() == ".upload" && store_.upload(entry.path().stem().string()).has_value();
    if (!complete) {
      spdlog::warn("removing interrupted upload {}", entry.path().string());
      fs::remove_all(entry.path());
    }
  }
}

}  // namespace btfvq::server
