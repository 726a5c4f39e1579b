#include "server/uploads.h"

#include <fcntl.h>
#include <unistd.h>

#include <spdlog/spdlog.h>

#include <cerrno>
#include <fstream>

#include <btfvq/error.h>
#include "server/errors.h"
#include "server/job_request.h"

namespace btfvq::server {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

int open_for_writing(const std::string& path, int flags) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_CLOEXEC | flags, 0644);
  if (fd < 0) throw_write_error(path, errno);
  return fd;
}

uint64_t size_or_zero(const fs::path& p) {
  std::error_code ec;
  const auto n = fs::file_size(p, ec);
  return ec ? 0 : uint64_t(n);
}

}  // namespace

// ---------------------------------------------------------------- UploadSink

UploadSink::UploadSink(Uploads& uploads, std::string id, const UploadRequest& request,
                       std::shared_ptr<std::atomic<uint64_t>> progress)
    : uploads_(uploads), id_(std::move(id)), request_(request), progress_(std::move(progress)) {
  if (request_.range) {
    path_ = uploads_.data_.partial_upload(id_).string();
    limit_ = request_.range->length();
    fd_ = open_for_writing(path_, O_APPEND);
  } else {
    file_.emplace(uploads_.data_.upload(id_).string());
    path_ = file_->temp_path();
    limit_ = uploads_.max_bytes_;
    fd_ = open_for_writing(path_, O_TRUNC);
  }
}

UploadSink::~UploadSink() {
  if (fd_ >= 0) ::close(fd_);
  file_.reset();
  if (!done_ && size_ > 0) {
    if (request_.range)
      spdlog::info("upload {}: piece at {} cut off after {} bytes (kept, to resume)", id_, request_.range->first,
                   size_);
    else
      spdlog::info("upload {} abandoned after {} bytes", id_, size_);
  }
  uploads_.release(id_);
}

bool UploadSink::write(const char* data, size_t size) {
  if (size_ + size > limit_) {
    too_large_ = true;
    return false;
  }
  write_all(fd_, data, size, path_);
  if (!request_.range) hash_.update(data, size);
  size_ += size;
  *progress_ = size_;
  uploads_.bytes_received_ += size;
  return true;
}

void UploadSink::close_file() {
  const int fd = std::exchange(fd_, -1);
  // A piece must be on disk before its bytes count as received; a whole upload is synced by commit().
  if (request_.range && ::fsync(fd) != 0) {
    const int err = errno;
    ::close(fd);
    throw_write_error(path_, err);
  }
  if (::close(fd) != 0 && errno != EINTR) throw_write_error(path_, errno);
}

json UploadSink::finish() { return request_.range ? finish_piece() : finish_whole(); }

json UploadSink::finish_whole() {
  close_file();
  const std::string sha = hash_.hex();
  if (!request_.sha256.empty() && request_.sha256 != sha)
    throw InputError("X-Sha256: the upload hashes to " + sha + ", not " + request_.sha256, "checksum_mismatch");
  file_->commit();
  uploads_.store_.insert_upload({id_, size_, sha, "complete", now_seconds()});
  done_ = true;
  spdlog::info("upload {} complete: {} bytes, sha256 {}", id_, size_, sha);
  return {{"id", id_}, {"size", size_}, {"sha256", sha}, {"state", "complete"}};
}

json UploadSink::finish_piece() {
  close_file();
  const ContentRange& r = *request_.range;
  const uint64_t received = r.first + size_;
  if (received < r.total) {
    done_ = true;
    return {{"id", id_}, {"state", "partial"}, {"received", received}, {"total", r.total}};
  }
  // The last piece: the whole file is hashed once here rather than piece by piece, because a piece
  // cut off anywhere leaves the hash of its bytes nowhere to be kept.
  const json meta = uploads_.partial_meta(id_).value_or(json::object());
  const std::string expected = meta.value("sha256", "");
  try {
    const std::string sha = sha256_file(path_);
    if (sha != expected)
      throw InputError("upload '" + id_ + "' hashes to " + sha + ", not " + expected +
                           " (X-Sha256 of its first piece); its pieces are discarded",
                       "checksum_mismatch");
    publish_file(path_, uploads_.data_.upload(id_).string());
    try {
      uploads_.store_.insert_upload({id_, r.total, sha, "complete", now_seconds()});
    } catch (...) {
      std::error_code ec;
      fs::remove(uploads_.data_.upload(id_), ec);  // a file the store does not list is not an upload
      throw;
    }
  } catch (...) {
    // A complete partial upload that cannot become an upload is of no use to resume from.
    uploads_.remove_partial(id_);
    throw;
  }
  uploads_.remove_partial(id_);
  done_ = true;
  spdlog::info("upload {} complete from pieces: {} bytes, sha256 {}", id_, r.total, expected);
  return {{"id", id_}, {"size", r.total}, {"sha256", expected}, {"state", "complete"}};
}

// ---------------------------------------------------------------- Uploads

Uploads::Uploads(Store& store, DataDir data, uint64_t max_bytes)
    : store_(store), data_(std::move(data)), max_bytes_(max_bytes) {}

std::unique_ptr<UploadSink> Uploads::begin(const std::string& id, const UploadRequest& request) {
  if (!valid_name(id)) throw InputError("upload id '" + id + "': use 1-64 of [A-Za-z0-9._-]", "invalid_request");
  const std::optional<uint64_t> size = request.range ? request.range->total : request.declared_size;
  if (size && *size > max_bytes_)
    throw TooLargeError("upload of " + std::to_string(*size) + " bytes exceeds the limit of " +
                        std::to_string(max_bytes_) + " bytes");
  if (request.range) return begin_piece(id, request);
  auto progress = reserve(id);
  try {
    return std::unique_ptr<UploadSink>(new UploadSink(*this, id, request, std::move(progress)));
  } catch (...) {
    release(id);
    throw;
  }
}

std::unique_ptr<UploadSink> Uploads::begin_piece(const std::string& id, const UploadRequest& request) {
  const ContentRange& r = *request.range;
  if (!request.declared_size || *request.declared_size != r.length())
    throw InputError("Content-Range bytes " + std::to_string(r.first) + "-" + std::to_string(r.last) + " is " +
                         std::to_string(r.length()) + " bytes; the body (Content-Length) must be as long",
                     "invalid_request");
  auto progress = reserve(id);
  try {
    const auto meta = partial_meta(id);
    const uint64_t received = meta ? size_or_zero(data_.partial_upload(id)) : 0;
    if (r.first != received)
      throw UploadOffsetError("upload '" + id + "' has received " + std::to_string(received) +
                                  " bytes; a piece must start there, not at " + std::to_string(r.first),
                              received);
    if (!meta) {
      if (request.sha256.size() != 64 || request.sha256.find_first_not_of("0123456789abcdef") != std::string::npos)
        throw InputError("the first piece of a resumable upload needs X-Sha256: the sha256 of the whole file "
                         "(64 hex digits)",
                         "invalid_request");
      // A .part without its .json is a leftover: the description goes last, so the pair means "started".
      const std::string part = data_.partial_upload(id).string();
      ::close(open_for_writing(part, O_TRUNC));
      write_file_atomically(data_.partial_upload_meta(id).string(),
                            json{{"id", id}, {"total", r.total}, {"sha256", request.sha256}, {"created", now_seconds()}}
                                .dump());
    } else {
      if ((*meta)["total"] != r.total)
        throw ConflictError("upload '" + id + "' is of " + (*meta)["total"].dump() + " bytes, not " +
                            std::to_string(r.total));
      if (!request.sha256.empty() && (*meta)["sha256"] != request.sha256)
        throw ConflictError("upload '" + id + "' is of the file with sha256 " + (*meta)["sha256"].get<std::string>() +
                            ", not " + request.sha256);
    }
    return std::unique_ptr<UploadSink>(new UploadSink(*this, id, request, std::move(progress)));
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

std::optional<json> Uploads::partial_meta(const std::string& id) {
  if (!fs::exists(data_.partial_upload(id))) return std::nullopt;
  std::ifstream in(data_.partial_upload_meta(id));
  if (!in) return std::nullopt;
  try {
    json meta = json::parse(in);
    if (meta.contains("total") && meta.contains("sha256")) return meta;
  } catch (const json::exception&) {
  }
  return std::nullopt;
}

void Uploads::remove_partial(const std::string& id) {
  std::error_code ec;
  fs::remove(data_.partial_upload_meta(id), ec);  // first: a .part alone is a leftover, never "started"
  fs::remove(data_.partial_upload(id), ec);
}

json Uploads::info(const std::string& id) {
  // No upload can have another id; and the id names files (a NUL or 300 characters made this a 500).
  if (!valid_name(id)) throw NotFoundError("no upload '" + id + "' (an upload id is 1-64 of [A-Za-z0-9._-])");
  if (auto u = store_.upload(id))
    return {{"id", u->id}, {"size", u->size}, {"sha256", u->sha256}, {"state", u->state}, {"created", u->created}};
  if (auto meta = partial_meta(id)) {
    const uint64_t received = size_or_zero(data_.partial_upload(id));
    return {{"id", id},
            {"state", "partial"},
            {"received", received},
            {"size", received},
            {"total", (*meta)["total"]},
            {"sha256", (*meta)["sha256"]},
            {"created", meta->value("created", 0.0)}};
  }
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
  for (const auto& entry : fs::directory_iterator(data_.partial_uploads())) {
    const std::string id = entry.path().stem().string();
    const auto ext = entry.path().extension();
    const bool paired = (ext == ".part" || ext == ".json") && entry.path().filename().string()[0] != '.' &&
                        partial_meta(id).has_value() && !store_.upload(id).has_value();
    if (!paired) {
      spdlog::warn("removing leftover of a resumable upload {}", entry.path().string());
      fs::remove_all(entry.path());
    }
  }
}

size_t Uploads::remove_abandoned(std::chrono::duration<double> age) {
  const auto cutoff = fs::file_time_type::clock::now() -
                      std::chrono::duration_cast<fs::file_time_type::duration>(age);
  size_t removed = 0;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(data_.partial_uploads(), ec)) {
    if (entry.path().extension() != ".json") continue;
    const std::string id = entry.path().stem().string();
    // Under the lock no piece of this id can begin meanwhile.
    std::lock_guard lock(mutex_);
    if (arriving_.count(id)) continue;
    const fs::path part = data_.partial_upload(id);
    const auto last = fs::exists(part, ec) ? fs::last_write_time(part, ec) : fs::last_write_time(entry.path(), ec);
    if (ec || last > cutoff) continue;
    spdlog::info("upload {}: no piece arrived for {:.0f} s; its {} bytes are removed", id, age.count(),
                 size_or_zero(part));
    remove_partial(id);
    ++removed;
  }
  return removed;
}

}  // namespace btfvq::server
