#pragma once
// The decode API for renderers (paper Sec. 4.6 and 5.2): open a .btfdb once, look materials up by
// name, and per shading point evaluate the BTF, sample a light direction for the view, its pdf, and
// the albedo. Installed by `make install` (with include/btfvq/colour.h, include/btfvq/directions.h and
// include/btfvq/error.h, which it uses); a plain C header over it is include/btfvq/btfvq_c.h.
//
// Conventions (docs/sampling.md):
//  - (u, v) are texture coordinates; the texel is (floor(u W), floor(v H)) wrapped, so the material
//    tiles: u = column / W, v = row / H (row 0 is the first row of the material's images). The
//    decoder interpolates over directions, not over texels.
//  - Directions are vectors in the tangent frame: z along the normal, x the tangent (azimuth 0), y
//    the bitangent (azimuth 90 degrees); they need not be normalised. A Direction (theta, phi in
//    degrees) is the same frame in spherical form (to_vector/to_direction).
//  - evaluate() returns what the decoder returns: gamma-encoded RGB 0..255 for LDR (not clamped
//    above), linear radiance for HDR; zero below the horizon.
//  - sample() and pdf() are in solid-angle measure (1/sr); pdf() is the density sample() draws from.
//
// Thread safety: a BtfDatabase and every BtfMaterial taken from it are immutable after open(); all
// their methods may be called from any number of threads at once. Handles share the data: the
// database stays alive as long as any handle does.
#include <cstddef>
#include <memory>
#include <string>
#include <vector>

#include <btfvq/colour.h>
#include <btfvq/directions.h>

namespace btfvq {

struct Database;
class Decoder;
class LightSampler;
struct BtfDatabaseState;

// A sampled light direction and its density.
struct BtfSample {
  Vec3 direction;  // unit vector, z >= 0
  double pdf = 0;  // 1/sr
};

class BtfMaterial {
 public:
  const std::string& name() const;
  int width() const;
  int height() const;
  bool hdr() const;
  size_t index() const { return index_; }  // in the database's material list

  Rgb evaluate(double u, double v, const Vec3& light, const Vec3& view) const;
  Rgb evaluate(double u, double v, const Direction& light, const Direction& view) const;
  // A light direction for `view` from two uniform numbers in [0, 1].
  BtfSample sample(double u, double v, const Vec3& view, double xi1, double xi2) const;
  double pdf(double u, double v, const Vec3& light, const Vec3& view) const;
  // Integral of evaluate() x cos(theta_i) over the hemisphere of lights (paper eq. 6), per channel.
  Rgb albedo(double u, double v, const Vec3& view) const;

  // The texel column / row a texture coordinate falls in (floor(u W), floor(v H), wrapped; 0 for a
  // non-finite coordinate): what the calls above use, so that batch callers building DecodeQuery
  // for Decoder::decode (python/, the batch layers) address the same texels.
  int texel_x(double u) const;
  int texel_y(double v) const;

 private:
  friend class BtfDatabase;
  BtfMaterial(std::shared_ptr<const BtfDatabaseState> state, size_t index) : state_(std::move(state)), index_(index) {}

  std::shared_ptr<const BtfDatabaseState> state_;
  size_t index_ = 0;
};

class BtfDatabase {
 public:
  // Reads and validates a .btfdb file once (its sections are packed and entropy-coded, so they are
  // decoded into memory rather than mapped), or imports a BTFBASE directory of the original
  // compressor. InputError for a missing or unreadable path, CorruptError (naming file and
  // section) for a damaged one.
  static BtfDatabase open(const std::string& path);
  // A database already in memory (e.g. imported from BTFBASE). Throws CorruptError if it does not validate.
  static BtfDatabase from_memory(Database db);

  std::vector<std::string> material_names() const;
  // NotFoundError naming the material and the database.
  BtfMaterial material(const std::string& name) const;
  BtfMaterial material(size_t index) const;

  // The layers underneath, for batch work (Decoder::decode on the compute device).
  const Database& database() const;
  const Decoder& decoder() const;
  const LightSampler& sampler() const;

 private:
  explicit BtfDatabase(std::shared_ptr<const BtfDatabaseState> state) : state_(std::move(state)) {}
  std::shared_ptr<const BtfDatabaseState> state_;
};

}  // namespace btfvq
