#include "pipeline/util/atomic_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>

#include <btfvq/error.h>

namespace btfvq {

namespace fs = std::filesystem;

namespace {

// fsync of one file or folder; returns errno or 0. A folder that cannot be opened for reading is
// not an error (some file systems refuse): the rename is then as durable as they allow. A close
// can report a failed write-back (ENOSPC on NFS), so it counts too.
int sync_one(const fs::path& p, bool folder) {
  const int fd = ::open(p.c_str(), (folder ? O_RDONLY | O_DIRECTORY : O_RDONLY) | O_CLOEXEC);
  if (fd < 0) return folder ? 0 : errno;
  int rc = ::fsync(fd) == 0 ? 0 : errno;
  if (::close(fd) != 0 && !rc && errno != EINTR) rc = errno;
  return (rc == EINVAL || rc == EROFS) ? 0 : rc;
}

int sync_tree(const fs::path& p) {
  std::error_code ec;
  if (!fs::is_directory(p, ec)) return sync_one(p, false);
  for (const auto& e : fs::recursive_directory_iterator(p, ec))
    if (int rc = sync_one(e.path(), e.is_directory()); rc) return rc;
  return sync_one(p, true);
}

}  // namespace

void throw_write_error(const std::string& path, int err) {
  const std::string what = "cannot write '" + path + "': " + std::strerror(err);
  if (err == ENOSPC) throw NoSpaceError(what + " (ENOSPC)");
  if (err == EDQUOT) throw NoSpaceError(what + " (EDQUOT)");
  throw Error("io", what);
}

void write_all(int fd, const void* data, size_t size, const std::string& path) {
  const auto* p = static_cast<const uint8_t*>(data);
  for (size_t done = 0; done < size;) {
    const ssize_t n = ::write(fd, p + done, size - done);
    if (n < 0 && errno == EINTR) continue;
    // A write that returns 0 for a non-empty buffer makes no progress; a full disk is the usual cause.
    if (n <= 0) throw_write_error(path, n < 0 ? errno : ENOSPC);
    done += size_t(n);
  }
}

AtomicFile::AtomicFile(const std::string& target) : target_(target) {
  static std::atomic<unsigned> counter{0};
  fs::path t(target);
  while (t.has_parent_path() && t.filename().empty()) t = t.parent_path();  // "dir/" -> "dir"
  target_ = t.string();
  const std::string tag = std::to_string(::getpid()) + "-" + std::to_string(counter++);
  temp_ = (t.parent_path() / ("." + t.stem().string() + ".tmp-" + tag + t.extension().string())).string();
}

AtomicFile::~AtomicFile() {
  if (committed_) return;
  std::error_code ec;
  fs::remove_all(temp_, ec);
}

void AtomicFile::commit() {
  try {
    publish_file(temp_, target_);
  } catch (const Error&) {
    std::error_code ec;
    fs::remove_all(temp_, ec);
    throw;
  }
  committed_ = true;
}

void publish_file(const std::string& temp, const std::string& target_path) {
  auto fail = [&](int err) { throw_write_error(target_path, err); };
  if (int rc = sync_tree(temp)) fail(rc);
  std::error_code ec;
  const fs::path target(target_path);
  if (fs::is_directory(fs::status(target, ec))) {
    // rename(2) cannot replace a non-empty folder: move the old one aside first, put it back on failure.
    const fs::path old = target.parent_path() / ("." + target.filename().string() + ".old-" +
                                                 fs::path(temp).filename().string());
    if (::rename(target.c_str(), old.c_str()) != 0) fail(errno);
    if (::rename(temp.c_str(), target.c_str()) != 0) {
      const int err = errno;
      ::rename(old.c_str(), target.c_str());
      fail(err);
    }
    fs::remove_all(old, ec);
  } else if (::rename(temp.c_str(), target.c_str()) != 0) {
    fail(errno);
  }
  // The rename is done: a folder that cannot be synced only makes it less durable, and failing
  // now would report an error for a file that is already in place.
  sync_one(fs::absolute(target).parent_path(), true);
}

std::string read_file(const std::string& path, const std::string& hint) {
  std::ifstream in(path, std::ios::binary);
  std::string bytes;
  if (in) bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  if (!in && !in.eof()) throw InputError("cannot read '" + path + "'" + hint);
  return bytes;
}

void write_file_atomically(const std::string& path, const void* data, size_t size) {
  AtomicFile file(path);
  const int fd = ::open(file.temp_path().c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw_write_error(path, errno);
  try {
    write_all(fd, data, size, path);
  } catch (...) {
    ::close(fd);
    throw;  // `file` removes the temporary
  }
  if (::close(fd) != 0 && errno != EINTR) throw_write_error(path, errno);
  file.commit();
}

}  // namespace btfvq
