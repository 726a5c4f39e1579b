#pragma once
// A progress bar for long operations (upload, watch, download). On a terminal it redraws one
// line on stderr; otherwise (logs, CI) it prints a plain line every few seconds. Never stdout,
// so that `btfvq submit ... | xargs btfvq watch` stays clean.
#include <chrono>
#include <cstdint>
#include <string>

namespace btfvq::cli {

class ProgressBar {
 public:
  explicit ProgressBar(std::string label, std::chrono::milliseconds plain_interval = std::chrono::seconds(5));
  ~ProgressBar();
  // `fraction` in 0..1 (negative: unknown); `note` is shown after the percentage.
  void update(double fraction, const std::string& note = "");
  // Bytes helper: "12.3 MiB / 40.0 MiB".
  void update_bytes(uint64_t done, uint64_t total);
  // Draws the final state and ends the line.
  void finish(const std::string& note = "");

  static std::string format_bytes(uint64_t bytes);

 private:
  void draw(double fraction, const std::string& note, bool force);
  std::string label_;
  bool tty_;
  bool finished_ = false;
  std::chrono::milliseconds plain_interval_;
  std::chrono::steady_clock::time_point last_draw_{};
  double last_fraction_ = -1;
  std::string last_note_;
};

}  // namespace btfvq::cli
