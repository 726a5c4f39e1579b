#pragma once
// SHA-256 (FIPS 180-4), incremental, so that uploads and downloads are hashed while they stream.
// The content hash of a database file is its identity on the wire (ETag, X-Content-Sha256).
#include <array>
#include <cstdint>
#include <string>

namespace btfvq {

class Sha256 {
 public:
  Sha256();
  void update(const void* data, size_t size);
  void update(const std::string& s) { update(s.data(), s.size()); }
  // Lower-case hex digest; the object must not be updated afterwards.
  std::string hex();

 private:
  void block(const uint8_t* p);
  std::array<uint32_t, 8> h_;
  std::array<uint8_t, 64> buffer_{};
  size_t buffered_ = 0;
  uint64_t length_ = 0;
};

std::string sha256_hex(const std::string& bytes);
// Hashes a whole file; throws InputError naming the file when it cannot be read.
std::string sha256_file(const std::string& path);

}  // namespace btfvq
