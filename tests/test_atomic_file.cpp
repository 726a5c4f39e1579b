// The one atomic-file writer (pipeline/util/atomic_file.h): a target holds its old content or the
// new, never a part, and a failure leaves nothing behind.
#include <doctest/doctest.h>

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>

#include <filesystem>
#include <fstream>
#include <sstream>

#include <btfvq/error.h>
#include "pipeline/util/atomic_file.h"
#include "support/test_paths.h"

using namespace btfvq;
namespace fs = std::filesystem;

namespace {

size_t entries(const fs::path& dir) {
  size_t n = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir)) ++n;
  return n;
}

}  // namespace

TEST_CASE("write_file_atomically creates and replaces a file and leaves no temporary") {
  const fs::path dir = test::scratch_dir("atomic-file");
  const fs::path target = dir / "db.btfdb";
  write_file_atomically(target.string(), std::string("first"));
  CHECK(test::file_bytes(target) == "first");
  write_file_atomically(target.string(), std::string("second, longer"));
  CHECK(test::file_bytes(target) == "second, longer");
  CHECK(entries(dir) == 1);
}

TEST_CASE("the temporary sits beside the target, hidden, with the target's extension") {
  const fs::path dir = test::scratch_dir("atomic-temp");
  AtomicFile a((dir / "x.png").string()), b((dir / "x.png").string());
  CHECK(fs::path(a.temp_path()).parent_path() == dir);
  CHECK(fs::path(a.temp_path()).filename().string()[0] == '.');
  CHECK(fs::path(a.temp_path()).extension() == ".png");
  CHECK(a.temp_path() != b.temp_path());
}

TEST_CASE("an uncommitted AtomicFile removes its temporary and keeps the old content") {
  const fs::path dir = test::scratch_dir("atomic-abandon");
  const fs::path target = dir / "keep.txt";
  write_file_atomically(target.string(), std::string("old"));
  {
    AtomicFile f(target.string());
    std::ofstream(f.temp_path()) << "half";
    CHECK(fs::exists(f.temp_path()));
  }
  CHECK(test::file_bytes(target) == "old");
  CHECK(entries(dir) == 1);
}

TEST_CASE("a folder target is replaced as a whole") {
  const fs::path dir = test::scratch_dir("atomic-folder");
  const fs::path target = dir / "sample";
  fs::create_directory(target);
  std::ofstream(target / "old.txt") << "old";
  AtomicFile f(target.string());
  fs::create_directory(f.temp_path());
  std::ofstream(fs::path(f.temp_path()) / "new.txt") << "new";
  f.commit();
  CHECK(test::file_bytes(target / "new.txt") == "new");
  CHECK_FALSE(fs::exists(target / "old.txt"));
  CHECK(entries(dir) == 1);
}

TEST_CASE("a write that cannot happen is an io Error naming the target, and changes nothing") {
  const fs::path dir = test::scratch_dir("atomic-fail");
  const fs::path target = dir / "missing-folder" / "db.btfdb";
  try {
    write_file_atomically(target.string(), std::string("x"));
    FAIL("no error");
  } catch (const Error& e) {
    CHECK(e.code() == "io");
    CHECK(std::string(e.what()).find(target.string()) != std::string::npos);
  }
  CHECK(entries(dir) == 0);
}

TEST_CASE("a full disk is a NoSpaceError whose message names ENOSPC; other failures stay io Errors") {
  // /dev/full refuses every write with ENOSPC, as a full file system does.
  const int fd = ::open("/dev/full", O_WRONLY | O_CLOEXEC);
  REQUIRE_MESSAGE(fd >= 0, "/dev/full is needed");
  const std::string bytes(100000, 'x');
  try {
    write_all(fd, bytes.data(), bytes.size(), "/some/db.btfdb");
    FAIL("/dev/full accepted the bytes");
  } catch (const NoSpaceError& e) {
    CHECK(e.code() == "no_space");
    const std::string m = e.what();
    CHECK(m.find("/some/db.btfdb") != std::string::npos);
    CHECK(m.size() >= 32);
    CHECK(m.substr(m.size() - 32) == "No space left on device (ENOSPC)");
  }
  ::close(fd);
  CHECK_THROWS_AS(throw_write_error("x", EDQUOT), NoSpaceError);
  try {
    throw_write_error("x", EACCES);
  } catch (const NoSpaceError&) {
    FAIL("EACCES is not a full disk");
  } catch (const Error& e) {
    CHECK(e.code() == "io");
  }
}
