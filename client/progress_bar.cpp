#include "client/progress_bar.h"

#include <unistd.h>

#include <cmath>
#include <cstdio>

namespace btfvq::cli {

ProgressBar::ProgressBar(std::string label, std::chrono::milliseconds plain_interval)
    : label_(std::move(label)), tty_(::isatty(STDERR_FILENO) != 0), plain_interval_(plain_interval) {}

ProgressBar::~ProgressBar() {
  if (tty_ && !finished_ && last_fraction_ >= 0) std::fputs("\n", stderr);
}

std::string ProgressBar::format_bytes(uint64_t bytes) {
  const char* units[] = {"B", "KiB", "MiB", "GiB", "TiB"};
  double v = double(bytes);
  int u = 0;
  while (v >= 1024 && u < 4) v /= 1024, ++u;
  char buf[32];
  std::snprintf(buf, sizeof buf, u == 0 ? "%.0f %s" : "%.1f %s", v, units[u]);
  return buf;
}

void ProgressBar::update(double fraction, const std::string& note) { draw(fraction, note, false); }

void ProgressBar::update_bytes(uint64_t done, uint64_t total) {
  draw(total > 0 ? double(done) / double(total) : -1, format_bytes(done) + (total > 0 ? " / " + format_bytes(total) : ""),
       false);
}

void ProgressBar::finish(const std::string& note) {
  if (finished_) return;
  draw(last_fraction_ < 0 ? 1.0 : last_fraction_, note.empty() ? last_note_ : note, true);
  if (tty_) std::fputs("\n", stderr);
  finished_ = true;
}

void ProgressBar::draw(double fraction, const std::string& note, bool force) {
  const auto now = std::chrono::steady_clock::now();
  const auto interval = tty_ ? std::chrono::milliseconds(100) : plain_interval_;
  const bool first = last_fraction_ < 0 && last_draw_ == std::chrono::steady_clock::time_point{};
  last_fraction_ = fraction;
  last_note_ = note;
  if (!force && !first && now - last_draw_ < interval) return;
  last_draw_ = now;
  const std::string percent = fraction >= 0 ? std::to_string(int(std::floor(std::min(fraction, 1.0) * 100))) + "%" : "";
  if (tty_) {
    constexpr int width = 30;
    const int filled = fraction >= 0 ? int(std::min(fraction, 1.0) * width) : 0;
    std::string bar(size_t(filled), '#');
    bar.append(size_t(width - filled), fraction >= 0 ? '.' : '?');
    std::fprintf(stderr, "\r\033[K%s [%s] %4s %s", label_.c_str(), bar.c_str(), percent.c_str(), note.c_str());
  } else {
    std::fprintf(stderr, "%s: %s %s\n", label_.c_str(), percent.c_str(), note.c_str());
  }
  std::fflush(stderr);
}

}  // namespace btfvq::cli
