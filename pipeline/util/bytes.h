#pragma once
// Fields of the project's own binary files (checkpoints, tile parts, raw samples), in memory order:
// they are read back by the same build on the same kind of machine, never exchanged.
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include <btfvq/error.h>

namespace btfvq {

class ByteWriter {
 public:
  template <class T>
  void put(T v) {
    bytes.append(reinterpret_cast<const char*>(&v), sizeof v);
  }
  template <class T>
  void put(const std::vector<T>& v) {
    put(uint64_t(v.size()));
    bytes.append(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T));
  }
  void put(const std::string& s) {
    put(uint64_t(s.size()));
    bytes += s;
  }
  std::string bytes;
};

// Reads what a ByteWriter wrote; a field past the end is a CorruptError "<what>: ...".
class ByteReader {
 public:
  ByteReader(const char* p, size_t n, std::string what) : p_(p), n_(n), what_(std::move(what)) {}
  template <class T>
  T get() {
    T v;
    std::memcpy(&v, take(sizeof v), sizeof v);
    return v;
  }
  template <class T>
  void get(std::vector<T>& v) {
    const uint64_t n = get<uint64_t>();
    if (n > (n_ - at_) / sizeof(T)) throw CorruptError(what_ + ": a length past the end");
    v.resize(size_t(n));
    std::memcpy(v.data(), take(size_t(n) * sizeof(T)), size_t(n) * sizeof(T));
  }
  std::string str() {
    const uint64_t n = get<uint64_t>();
    if (n > n_ - at_) throw CorruptError(what_ + ": a length past the end");
    return std::string(take(size_t(n)), size_t(n));
  }
  size_t left() const { return n_ - at_; }
  bool done() const { return at_ == n_; }
  const char* take(size_t n) {
    if (n > n_ - at_) throw CorruptError(what_ + ": truncated");
    const char* p = p_ + at_;
    at_ += n;
    return p;
  }

 private:
  const char* p_;
  size_t n_, at_ = 0;
  std::string what_;
};

}  // namespace btfvq
