#pragma once
// The one way btfvq publishes a file or a folder: write it under a temporary name beside the target,
// fsync it, rename it over the target, fsync the folder. A reader (the server, a client resuming a
// download, a crashed run's next start) sees the old content or the new one, never a half-written
// file; a failure (full disk, no permission) removes the temporary and leaves the old content.
#include <cerrno>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include <btfvq/error.h>

namespace btfvq {

// A write failed because the file system is full (ENOSPC) or the quota is used up (EDQUOT): a
// condition of the machine, not of the data, that clears once space is freed, so callers tell it
// apart (the server answers 507 and a job records it). The message names the errno, e.g.
// "cannot write 'x': No space left on device (ENOSPC)".
class NoSpaceError : public Error {
 public:
  explicit NoSpaceError(const std::string& message) : Error("no_space", message) {}
};

// Whether `err` (an errno) means that the file system has no room.
inline bool is_no_space(int err) { return err == ENOSPC || err == EDQUOT; }

// The error of a failed write, fsync, close or rename of `path`: NoSpaceError for ENOSPC and
// EDQUOT (naming the errno), else Error("io") with the system's reason.
[[noreturn]] void throw_write_error(const std::string& path, int err);

// Writes all `size` bytes to `fd` (short writes and EINTR are retried); throws throw_write_error().
void write_all(int fd, const void* data, size_t size, const std::string& path);

class AtomicFile {
 public:
  // `target` is a file or a folder path. The temporary lives in the same folder (rename is atomic
  // only within one file system), is hidden, unique per process and call, and keeps the target's
  // extension (OpenImageIO picks an image format from it).
  explicit AtomicFile(const std::string& target);
  ~AtomicFile();  // removes the temporary (file or folder tree) unless committed
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  const std::string& temp_path() const { return temp_; }
  const std::string& target() const { return target_; }

  // fsyncs what was written at temp_path() (a file, or every file of a folder), renames it over the
  // target and fsyncs the target's folder. An existing folder target is replaced as a whole. Throws
  // throw_write_error()'s error naming the target; the temporary is removed then.
  void commit();

 private:
  std::string target_, temp_;
  bool committed_ = false;
};

// The publishing step of AtomicFile on its own, for a temporary that must outlive the process (a
// resumable download's partial file): fsync `temp`, rename it over `target`, fsync the folder.
// The error (throw_write_error()) names the target; `temp` is left in place on failure.
void publish_file(const std::string& temp, const std::string& target);

// Writes `size` bytes to `path` through an AtomicFile; every write, the fsync, the close and the
// rename are checked, and any failure removes the temporary. The error (throw_write_error()) names
// the path and the reason.
void write_file_atomically(const std::string& path, const void* data, size_t size);
inline void write_file_atomically(const std::string& path, const std::vector<uint8_t>& bytes) {
  write_file_atomically(path, bytes.data(), bytes.size());
}
inline void write_file_atomically(const std::string& path, const std::string& text) {
  write_file_atomically(path, text.data(), text.size());
}

// The whole file, or InputError "cannot read '<path>'<hint>".
std::string read_file(const std::string& path, const std::string& hint = "");

}  // namespace btfvq
