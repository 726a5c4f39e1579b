#pragma once
// The layout of the server's data directory, the one place that names its files:
//   <data>/btfvq.sqlite                  jobs, uploads, versions (the Store)
//   <data>/uploads/<id>.upload           complete uploads
//   <data>/partial-uploads/<id>.part     a resumable upload's bytes so far (PUT with Content-Range)
//   <data>/partial-uploads/<id>.json     its description (total size, sha256); a .part without it,
//                                        or it without a .part, is a leftover
//   <data>/databases/<name>/v<N>.btfdb   published versions
//   <data>/work/<job id>/                a running job's checkpoints (pipeline/encode/checkpoint.h)
// Each file is written under a hidden temporary name beside it (pipeline/util/atomic_file.h), so a
// file there that the store does not list is a leftover of a crash. The exception is a .part: it
// grows in place, piece by piece, because its bytes so far are what a client resumes from; once
// complete and verified it is renamed to uploads/ (publish_file).
#include <cstdint>
#include <filesystem>
#include <string>

namespace btfvq::server {

class DataDir {
 public:
  explicit DataDir(std::filesystem::path root) : root_(std::move(root)) {}

  const std::filesystem::path& root() const { return root_; }
  std::filesystem::path store() const { return root_ / "btfvq.sqlite"; }
  std::filesystem::path uploads() const { return root_ / "uploads"; }
  std::filesystem::path upload(const std::string& id) const { return uploads() / (id + ".upload"); }
  std::filesystem::path partial_uploads() const { return root_ / "partial-uploads"; }
  std::filesystem::path partial_upload(const std::string& id) const { return partial_uploads() / (id + ".part"); }
  std::filesystem::path partial_upload_meta(const std::string& id) const {
    return partial_uploads() / (id + ".json");
  }
  std::filesystem::path databases() const { return root_ / "databases"; }
  std::filesystem::path work() const { return root_ / "work"; }
  std::filesystem::path work(const std::string& job) const { return work() / job; }
  // Relative to the root, as the store records it, so that a data directory can be moved.
  static std::string version(const std::string& database, int64_t n) {
    return (std::filesystem::path("databases") / database / ("v" + std::to_string(n) + ".btfdb")).string();
  }

 private:
  std::filesystem::path root_;
};

}  // namespace btfvq::server
