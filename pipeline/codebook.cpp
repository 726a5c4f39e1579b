#include "pipeline/codebook.h"

#include <nlohmann/json.hpp>

#include <btfvq/error.h>

namespace btfvq {

Codebooks::Codebooks(const AngularGrid& g)
    : grid(g),
      p1(size_t(g.n_beta)),
      c(2),
      i1(size_t(g.n_beta)),
      i2(size_t(g.n_alpha)),
      p2_index(size_t(g.n_alpha)),
      p2_scale(size_t(g.n_alpha)),
      m(2),
      p3_index(size_t(g.n_theta_v)),
      p3_scale(size_t(g.n_theta_v)),
      p4_index(size_t(g.n_phi_v)),
      p4_scale(size_t(g.n_phi_v)) {}

const char* codebook_name(CodebookId id) {
  static const char* names[kCodebookCount] = {"P1", "C", "I1", "I2", "P2", "M", "P3", "P4"};
  const auto i = size_t(id);
  return i < size_t(kCodebookCount) ? names[i] : "?";
}

CodebookSizes CodebookSizes::of(const Codebooks& k) {
  CodebookSizes z;
  z[CodebookId::P1] = k.p1.rows();
  z[CodebookId::C] = k.c.rows();
  z[CodebookId::I1] = k.i1.rows();
  z[CodebookId::I2] = k.i2.rows();
  z[CodebookId::P2] = k.p2_index.rows();
  z[CodebookId::M] = k.m.rows();
  z[CodebookId::P3] = k.p3_index.rows();
  z[CodebookId::P4] = k.p4_index.rows();
  return z;
}

void to_json(nlohmann::json& j, const CodebookSizes& z) {
  j = nlohmann::json::object();
  for (CodebookId id : kAllCodebooks) j[codebook_name(id)] = z[id];
}

void from_json(const nlohmann::json& j, CodebookSizes& z) {
  for (CodebookId id : kAllCodebooks) z[id] = j.is_object() ? j.value(codebook_name(id), size_t(0)) : 0;
}

const Material* Database::find(const std::string& name) const {
  for (const auto& m : materials)
    if (m.name == name) return &m;
  return nullptr;
}

namespace {

void check_column(const Table<uint32_t>& t, size_t col, size_t limit, const char* name, const char* target) {
  for (size_t r = 0; r < t.rows(); ++r)
    if (t.at(r, col) >= limit)
      throw CorruptError(std::string(name) + " row " + std::to_string(r) + " column " + std::to_string(col) +
                         ": index " + std::to_string(t.at(r, col)) + " is past the end of " + target + " (" +
                         std::to_string(limit) + " entries)");
}

void check_all(const Table<uint32_t>& t, size_t limit, const char* name, const char* target) {
  for (size_t c = 0; c < t.cols(); ++c) check_column(t, c, limit, name, target);
}

}  // namespace

void Database::validate() const {
  const Codebooks& k = codebooks;
  check_all(k.i1, k.c.rows(), "I1", "C");
  check_all(k.i2, k.i1.rows(), "I2", "I1");
  check_all(k.p2_index, k.p1.rows(), "P2", "P1");
  check_column(k.m, 0, k.p2_index.rows(), "M", "P2");
  check_column(k.m, 1, k.i2.rows(), "M", "I2");
  check_all(k.p3_index, k.m.rows(), "P3", "M");
  check_all(k.p4_index, k.p3_index.rows(), "P4", "P3");
  for (const auto& mat : materials) {
    if (mat.p6_index.size() != size_t(mat.width) * size_t(mat.height) || mat.p6_scale.size() != mat.p6_index.size())
      throw CorruptError("material '" + mat.name + "': P6 does not have width x height entries");
    for (size_t i = 0; i < mat.p6_index.size(); ++i)
      if (mat.p6_index[i] >= int64_t(k.p4_index.rows()) || mat.p6_index[i] < -1)
        throw CorruptError("material '" + mat.name + "' P6 row " + std::to_string(i / size_t(mat.width)) + " column " +
                           std::to_string(i % size_t(mat.width)) + ": index " + std::to_string(mat.p6_index[i]) +
                           " is past the end of P4 (" + std::to_string(k.p4_index.rows()) + " entries)");
  }
}

}  // namespace btfvq
