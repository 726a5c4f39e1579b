#pragma once
// The one way btfvq publishes a file or a folder: write it under a temporary name beside the target,
// fsync it, rename it over the target, fsync the folder. A reader (the server, a client resuming a
// download, a crashed run's next start) sees the old content or the new one, never a half-written
// file; a failure (full disk, no permission) removes the temporary and leaves the old content.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace btfvq {

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
  // Error("io") naming the target and the system's reason; the temporary is removed then.
  void commit();

 private:
  std::string target_, temp_;
  bool committed_ = false;
};

// The publishing step of AtomicFile on its own, for a temporary that must outlive the process (a
// resumable download's partial file): fsync `temp`, rename it over `target`, fsync the folder.
// Error("io") names the target; `temp` is left in place on failure.
void publish_file(const std::string& temp, const std::string& target);

// Writes `size` bytes to `path` through an AtomicFile. Error("io") names the path and the reason
// (e.g. "No space left on device").
void write_file_atomically(const std::string& path, const void* data, size_t size);
inline void write_file_atomically(const std::string& path, const std::vector<uint8_t>& bytes) {
  write_file_atomically(path, bytes.data(), bytes.size());
}
inline void write_file_atomically(const std::string& path, const std::string& text) {
  write_file_atomically(path, text.data(), text.size());
}

}  // namespace btfvq
