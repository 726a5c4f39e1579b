#pragma once
// Progress on stderr for long local operations: a redrawn bar on a terminal, a plain line every few
// seconds otherwise (logs, CI). Thread-compatible: callers serialise updates.
#include <chrono>
#include <string>

namespace btfvq::cli {

class Progress {
 public:
  explicit Progress(std::string label);
  ~Progress();
  void update(double fraction, const std::string& note = "");
  void finish(const std::string& note = "");

 private:
  std::string label_;
  bool tty_;
  bool done_ = false;
  std::chrono::steady_clock::time_point start_, last_;
  double fraction_ = 0;
  std::string note_;
};

}  // namespace btfvq::cli
