#include <btfvq/directions.h>

#include <algorithm>
#include <cmath>

namespace btfvq {

const std::vector<Direction>& bonn81() {
  static const std::vector<Direction> dirs = [] {
    std::vector<Direction> d{{0, 0}};
    const int thetas[] = {15, 30, 45, 60, 75};
    const int steps[] = {60, 30, 20, 18, 15};
    for (int r = 0; r < 5; ++r)
      for (int phi = 0; phi < 360; phi += steps[r]) d.push_back({double(thetas[r]), double(phi)});
    return d;
  }();
  return dirs;
}

Vec3 to_vector(const Direction& d) {
  const double t = d.theta * kDeg, p = d.phi * kDeg;
  return {std::cos(p) * std::sin(t), std::sin(p) * std::sin(t), std::cos(t)};
}

Direction to_direction(const Vec3& v) {
  const double len = std::sqrt(v.x * v.x + v.y * v.y + v.z * v.z);
  const double theta = std::acos(std::clamp(v.z / len, -1.0, 1.0)) / kDeg;
  double phi = std::atan2(v.y, v.x) / kDeg;
  if (phi < 0) phi += 360;
  if (phi >= 360) phi -= 360;
  return {theta, phi};
}

double angle_between(const Direction& a, const Direction& b) {
  const Vec3 u = to_vector(a), v = to_vector(b);
  return std::acos(std::clamp(u.x * v.x + u.y * v.y + u.z * v.z, -1.0, 1.0));
}

}  // namespace btfvq
