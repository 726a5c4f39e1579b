#include "client/progress.h"

#include <unistd.h>

#include <algorithm>
#include <cstdio>

namespace btfvq::cli {

Progress::Progress(std::string label)
    : label_(std::move(label)), tty_(::isatty(2)), start_(std::chrono::steady_clock::now()), last_(start_) {}

Progress::~Progress() {
  if (!done_) finish();
}

void Progress::update(double fraction, const std::string& note) {
  fraction_ = std::clamp(fraction, 0.0, 1.0);
  note_ = note;
  const auto now = std::chrono::steady_clock::now();
  const double since = std::chrono::duration<double>(now - last_).count();
  if (since < (tty_ ? 0.1 : 5.0)) return;
  last_ = now;
  const double elapsed = std::chrono::duration<double>(now - start_).count();
  if (tty_) {
    const int width = 30, filled = int(fraction_ * width);
    std::fprintf(stderr, "\r%-24s [%s%s] %3.0f%% %6.1fs %s\033[K", label_.c_str(), std::string(size_t(filled), '#').c_str(),
                 std::string(size_t(width - filled), '.').c_str(), 100 * fraction_, elapsed, note_.c_str());
  } else {
    std::fprintf(stderr, "%s: %.0f%% after %.1fs %s\n", label_.c_str(), 100 * fraction_, elapsed, note_.c_str());
  }
  std::fflush(stderr);
}

void Progress::finish(const std::string& note) {
  if (done_) return;
  done_ = true;
  const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  const std::string n = note.empty() ? note_ : note;
  if (tty_) std::fprintf(stderr, "\r%-24s [%s] 100%% %6.1fs %s\033[K\n", label_.c_str(), std::string(30, '#').c_str(), elapsed, n.c_str());
  else std::fprintf(stderr, "%s: done in %.1fs %s\n", label_.c_str(), elapsed, n.c_str());
}

}  // namespace btfvq::cli
