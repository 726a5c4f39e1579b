#pragma once
// Directions on the hemisphere and the Bonn/UBO2003 sampling of 81 directions.
#include <vector>

namespace btfvq {

// A direction on the upper hemisphere in degrees: theta from the normal, phi the azimuth.
struct Direction {
  double theta = 0;
  double phi = 0;
  bool operator==(const Direction& o) const { return theta == o.theta && phi == o.phi; }
};

// The 81 Bonn directions: (0, 0), then rings theta = 15, 30, 45, 60, 75 with phi steps 60, 30, 20,
// 18, 15 degrees starting at phi 0 (6, 12, 18, 20, 24 directions). Light and view use the same set.
const std::vector<Direction>& bonn81();

// Unit vector of a direction (z along the normal).
struct Vec3 {
  double x = 0, y = 0, z = 0;
};
Vec3 to_vector(const Direction& d);
Direction to_direction(const Vec3& v);  // v need not be normalised; phi in [0, 360)

// Great-circle angle between two directions, in radians.
double angle_between(const Direction& a, const Direction& b);

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

}  // namespace btfvq
