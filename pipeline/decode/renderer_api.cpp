#include <btfvq/renderer_api.h>

#include <cmath>
#include <filesystem>

#include "pipeline/decode/albedo.h"
#include "pipeline/io/btfbase.h"
#include "pipeline/codebook.h"
#include "pipeline/format/database.h"
#include "pipeline/decode/decoder.h"
#include <btfvq/error.h>
#include "pipeline/decode/sampling.h"

namespace btfvq {

// Built once, never changed: the decoder and the sampler hold references into `db`, which lives
// here at a fixed address.
struct BtfDatabaseState {
  std::string where;
  Database db;
  std::unique_ptr<Decoder> decoder;
  std::unique_ptr<LightSampler> sampler;

  BtfDatabaseState(Database d, std::string w) : where(std::move(w)), db(std::move(d)) {
    decoder = std::make_unique<Decoder>(db);
    sampler = std::make_unique<LightSampler>(*decoder);
  }
};

BtfDatabase BtfDatabase::open(const std::string& path) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec))
    return BtfDatabase(std::make_shared<const BtfDatabaseState>(import_btfbase(path), path));
  return BtfDatabase(std::make_shared<const BtfDatabaseState>(read_database(path), path));
}

BtfDatabase BtfDatabase::from_memory(Database db) {
  return BtfDatabase(std::make_shared<const BtfDatabaseState>(std::move(db), "database"));
}

std::vector<std::string> BtfDatabase::material_names() const {
  std::vector<std::string> names;
  for (const Material& m : state_->db.materials) names.push_back(m.name);
  return names;
}

BtfMaterial BtfDatabase::material(const std::string& name) const {
  const auto& mats = state_->db.materials;
  for (size_t i = 0; i < mats.size(); ++i)
    if (mats[i].name == name) return BtfMaterial(state_, i);
  throw NotFoundError("no material '" + name + "' in " + state_->where);
}

BtfMaterial BtfDatabase::material(size_t index) const {
  if (index >= state_->db.materials.size())
    throw NotFoundError("material index " + std::to_string(index) + " is past the end of " + state_->where + " (" +
                        std::to_string(state_->db.materials.size()) + " materials)");
  return BtfMaterial(state_, index);
}

const Database& BtfDatabase::database() const { return state_->db; }
const Decoder& BtfDatabase::decoder() const { return *state_->decoder; }
const LightSampler& BtfDatabase::sampler() const { return *state_->sampler; }

const std::string& BtfMaterial::name() const { return state_->db.materials[index_].name; }
int BtfMaterial::width() const { return state_->db.materials[index_].width; }
int BtfMaterial::height() const { return state_->db.materials[index_].height; }
bool BtfMaterial::hdr() const { return state_->db.materials[index_].dynamic == Dynamic::HDR; }

namespace {
// floor(t n) for any finite t; the decoder wraps it into the material. Non-finite -> 0.
int texel_coordinate(double t, int n) {
  if (!std::isfinite(t)) return 0;
  const double f = t - std::floor(t);  // wrap first so huge coordinates stay in int range
  return std::min(int(f * n), n - 1);
}
}  // namespace

int BtfMaterial::texel_x(double u) const { return texel_coordinate(u, std::max(width(), 1)); }
int BtfMaterial::texel_y(double v) const { return texel_coordinate(v, std::max(height(), 1)); }

Rgb BtfMaterial::evaluate(double u, double v, const Vec3& light, const Vec3& view) const {
  return state_->decoder->evaluate(index_, texel_x(u), texel_y(v), to_direction(light), to_direction(view));
}

Rgb BtfMaterial::evaluate(double u, double v, const Direction& light, const Direction& view) const {
  return state_->decoder->evaluate(index_, texel_x(u), texel_y(v), light, view);
}

BtfSample BtfMaterial::sample(double u, double v, const Vec3& view, double xi1, double xi2) const {
  const LightSample s = state_->sampler->sample(index_, texel_x(u), texel_y(v), view, xi1, xi2);
  return {s.direction, s.pdf};
}

double BtfMaterial::pdf(double u, double v, const Vec3& light, const Vec3& view) const {
  return state_->sampler->pdf(index_, texel_x(u), texel_y(v), light, view);
}

Rgb BtfMaterial::albedo(double u, double v, const Vec3& view) const {
  return btfvq::albedo(*state_->decoder, index_, texel_x(u), texel_y(v), view);
}

}  // namespace btfvq
