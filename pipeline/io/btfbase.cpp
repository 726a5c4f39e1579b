#include "pipeline/io/btfbase.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include <btfvq/error.h>
#include "pipeline/util/atomic_file.h"

namespace btfvq {

namespace fs = std::filesystem;

namespace {

// ---------------------------------------------------------------------------------------------
// Reading: a whole file in one buffer, numbers by std::from_chars (proposte is 8 MB of text).

std::string read_file(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError("BTFBASE file " + path.filename().string() + " is missing (" + path.string() + ")");
  std::string text;
  in.seekg(0, std::ios::end);
  text.resize(size_t(in.tellg()));
  in.seekg(0);
  in.read(text.data(), std::streamsize(text.size()));
  if (!in) throw InputError("cannot read BTFBASE file " + path.string());
  return text;
}

// A cursor over the text of one file that knows its line number, for messages that name the spot.
class Cursor {
 public:
  Cursor(const std::string& text, std::string file) : p_(text.data()), end_(text.data() + text.size()), file_(std::move(file)) {}

  const std::string& file() const { return file_; }
  size_t line() const { return line_; }
  bool at_end() const { return p_ == end_; }
  bool at_line_end() {
    skip_blanks();
    return p_ == end_ || *p_ == '\n';
  }
  void next_line() {
    while (p_ != end_ && *p_ != '\n') ++p_;
    if (p_ != end_) {
      ++p_;
      ++line_;
    }
  }
  // Skips blank lines; true when only whitespace remains.
  bool only_space_left() {
    while (p_ != end_ && (*p_ == ' ' || *p_ == '\t' || *p_ == '\r' || *p_ == '\n')) {
      if (*p_ == '\n') ++line_;
      ++p_;
    }
    return p_ == end_;
  }

  // Parses the next number of the current line into v; false at the end of the line.
  template <class T>
  bool number(T& v, const std::string& where) {
    if (at_line_end()) return false;
    const char* start = p_;
    auto [q, ec] = std::from_chars(p_, end_, v);
    const bool bad_end = q != end_ && !is_space(*q);
    if (ec != std::errc() || bad_end || !finite(v)) {
      const char* tok_end = start;
      while (tok_end != end_ && !is_space(*tok_end)) ++tok_end;
      throw CorruptError(file_ + " " + where + " (line " + std::to_string(line_) + "): '" +
                         std::string(start, std::min<size_t>(size_t(tok_end - start), 40)) + "' is not " +
                         (std::is_integral_v<T> ? "an integer" : "a number"));
    }
    p_ = q;
    return true;
  }

 private:
  static bool is_space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n'; }
  template <class T>
  static bool finite(T v) {
    if constexpr (std::is_floating_point_v<T>) return std::isfinite(v);
    else return true;
  }
  void skip_blanks() {
    while (p_ != end_ && (*p_ == ' ' || *p_ == '\t' || *p_ == '\r')) ++p_;
  }

  const char* p_;
  const char* end_;
  std::string file_;
  size_t line_ = 1;
};

template <class T>
struct Matrix {
  std::string file;
  size_t rows = 0, cols = 0;
  std::vector<T> data;
  const T& at(size_t r, size_t c) const { return data[r * cols + c]; }
};

// Reads "rows cols min max" and then rows lines of cols numbers; anything else is CorruptError
// naming the file and the row.
template <class T>
Matrix<T> read_matrix(const fs::path& dir, const std::string& file) {
  const std::string text = read_file(dir / file);
  Cursor cur(text, file);
  Matrix<T> m;
  m.file = file;
  int64_t rows = -1, cols = -1;
  double lo = 0, hi = 0;
  if (!cur.number(rows, "header") || !cur.number(cols, "header") || !cur.number(lo, "header") ||
      !cur.number(hi, "header") || !cur.at_line_end())
    throw CorruptError(file + " line 1: header must be 'rows cols min max'");
  if (rows < 0 || cols <= 0 || rows > (int64_t(1) << 28) || cols > 4096)
    throw CorruptError(file + " line 1: implausible size " + std::to_string(rows) + " x " + std::to_string(cols));
  m.rows = size_t(rows);
  m.cols = size_t(cols);
  m.data.resize(m.rows * m.cols);
  cur.next_line();
  for (size_t r = 0; r < m.rows; ++r) {
    const std::string where = "row " + std::to_string(r);
    if (cur.at_end())
      throw CorruptError(file + " is truncated: the header declares " + std::to_string(m.rows) + " rows but the data ends at " +
                         where);
    T* out = m.data.data() + r * m.cols;
    for (size_t c = 0; c < m.cols; ++c)
      if (!cur.number(out[c], where))
        throw CorruptError(file + " " + where + " (line " + std::to_string(cur.line()) + ") has " + std::to_string(c) +
                           " values, the header declares " + std::to_string(m.cols) + " columns");
    if (!cur.at_line_end())
      throw CorruptError(file + " " + where + " (line " + std::to_string(cur.line()) + ") has more than the " +
                         std::to_string(m.cols) + " values the header declares");
    cur.next_line();
  }
  if (!cur.only_space_left())
    throw CorruptError(file + " line " + std::to_string(cur.line()) + ": data after the " + std::to_string(m.rows) +
                       " rows the header declares");
  return m;
}

template <class T>
void expect_cols(const Matrix<T>& m, size_t cols, const std::string& what) {
  if (m.cols != cols)
    throw CorruptError(m.file + " line 1: " + std::to_string(m.cols) + " columns, but " + what + " needs " +
                       std::to_string(cols));
}

template <class A, class B>
void expect_same_shape(const Matrix<A>& a, const Matrix<B>& b) {
  if (a.rows != b.rows || a.cols != b.cols)
    throw CorruptError(b.file + " line 1: " + std::to_string(b.rows) + " x " + std::to_string(b.cols) + " does not match " +
                       a.file + " (" + std::to_string(a.rows) + " x " + std::to_string(a.cols) + ")");
}

std::string index_error(const std::string& file, size_t row, size_t col, int64_t v, size_t limit,
                        const std::string& target) {
  return file + " row " + std::to_string(row) + " (line " + std::to_string(row + 2) + ") column " + std::to_string(col) +
         ": index " + std::to_string(v) + (v < 0 ? " is negative" : " >= " + std::to_string(limit) + " entries of " + target);
}

// Copies the index columns [col0, col0 + table.cols()) of m into a table, checking each against the
// size of its target code-book.
void to_index_table(const Matrix<int64_t>& m, Table<uint32_t>& table, size_t limit, const std::string& target) {
  expect_cols(m, table.cols(), "the grid");
  table.resize_rows(m.rows);
  for (size_t r = 0; r < m.rows; ++r)
    for (size_t c = 0; c < m.cols; ++c) {
      const int64_t v = m.at(r, c);
      if (v < 0 || uint64_t(v) >= limit) throw CorruptError(index_error(m.file, r, c, v, limit, target));
      table.at(r, c) = uint32_t(v);
    }
}

void to_float_table(const Matrix<float>& m, Table<float>& table) {
  expect_cols(m, table.cols(), "the grid");
  table.data() = m.data;
}

// ---------------------------------------------------------------------------------------------
// all_materialInfo.txt

struct MaterialLine {
  std::string name;
  int rows = 0, cols = 0;
  double hdr_value = 0;
};

struct MaterialInfo {
  int loaded = 0;
  int n_views = 81, n_lights = 81;
  AngularGrid grid;
  std::vector<int64_t> sizes;  // P1 C I1 M P2 I2 P3 P34 P4 reserve
  std::vector<MaterialLine> materials;
};

constexpr const char* kInfo = "all_materialInfo.txt";

std::vector<std::string> split_lines(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    lines.push_back(line);
  }
  return lines;
}

std::vector<std::string> tokens(const std::string& line) {
  std::istringstream in(line);
  std::vector<std::string> out;
  for (std::string t; in >> t;) out.push_back(t);
  return out;
}

template <class T>
T info_number(const std::string& token, size_t line, const char* what) {
  T v{};
  auto [q, ec] = std::from_chars(token.data(), token.data() + token.size(), v);
  if (ec != std::errc() || q != token.data() + token.size())
    throw CorruptError(std::string(kInfo) + " line " + std::to_string(line) + ": " + what + " '" + token +
                       "' is not a number");
  return v;
}

std::vector<int64_t> info_ints(const std::vector<std::string>& lines, size_t line, size_t at_least, const char* what) {
  const auto t = tokens(lines[line - 1]);
  if (t.size() < at_least)
    throw CorruptError(std::string(kInfo) + " line " + std::to_string(line) + ": expected " + std::to_string(at_least) +
                       " numbers (" + what + "), found " + std::to_string(t.size()));
  std::vector<int64_t> v;
  for (const auto& s : t) v.push_back(info_number<int64_t>(s, line, what));
  return v;
}

MaterialInfo read_material_info(const fs::path& dir) {
  const auto lines = split_lines(read_file(dir / kInfo));
  if (lines.size() < 14)
    throw CorruptError(std::string(kInfo) + " is truncated: " + std::to_string(lines.size()) +
                       " lines, the header alone has 14");
  MaterialInfo info;
  info.loaded = int(info_ints(lines, 2, 1, "materials loaded")[0]);
  info.n_views = int(info_ints(lines, 8, 1, "number of views")[0]);
  info.n_lights = int(info_ints(lines, 9, 1, "number of lights")[0]);
  if (info.n_views <= 0 || info.n_lights <= 0)
    throw CorruptError(std::string(kInfo) + " lines 8-9: view and light counts must be positive");
  const auto g = info_ints(lines, 11, 8, "useCosBeta n_beta 0 n_alpha 0 n_theta 0 n_phi");
  if (g[0] != 1)
    throw InputError(std::string(kInfo) + " line 11: useCosBeta = " + std::to_string(g[0]) +
                     " is not supported (only the grid uniform in sin(beta), useCosBeta = 1)");
  info.grid.n_beta = int(g[1]);
  info.grid.n_alpha = int(g[3]);
  info.grid.n_theta_v = int(g[5]);
  info.grid.n_phi_v = int(g[7]);
  try {
    info.grid.validate();
  } catch (const InputError& e) {
    throw CorruptError(std::string(kInfo) + " line 11: " + e.what());
  }
  info.sizes = info_ints(lines, 13, 9, "code-book sizes P1 C I1 M P2 I2 P3 P34 P4");
  for (size_t l = 15; l <= lines.size(); ++l) {
    const auto t = tokens(lines[l - 1]);
    if (t.empty()) continue;
    if (t.size() != 9)
      throw CorruptError(std::string(kInfo) + " line " + std::to_string(l) +
                         ": a material line is 'name inPath outPath tmpPath rowOffset colOffset rows cols hdrValue'");
    MaterialLine m;
    m.name = t[0];
    if (m.name == "all" || m.name.find_first_of("/\\") != std::string::npos)
      throw CorruptError(std::string(kInfo) + " line " + std::to_string(l) + ": material name '" + m.name +
                         "' is not a plain file-name prefix");
    m.rows = info_number<int>(t[6], l, "rows");
    m.cols = info_number<int>(t[7], l, "cols");
    m.hdr_value = info_number<double>(t[8], l, "hdrValue");
    if (m.rows <= 0 || m.cols <= 0)
      throw CorruptError(std::string(kInfo) + " line " + std::to_string(l) + ": material '" + m.name +
                         "' has no texels");
    info.materials.push_back(m);
  }
  if (int(info.materials.size()) != info.loaded)
    throw CorruptError(std::string(kInfo) + " line 2 says " + std::to_string(info.loaded) + " materials, but " +
                       std::to_string(info.materials.size()) + " material lines follow line 14");
  return info;
}

void check_size(const MaterialInfo& info, size_t slot, const char* name, size_t rows, const std::string& file) {
  if (info.sizes[slot] != int64_t(rows))
    throw CorruptError(std::string(kInfo) + " line 13: " + name + " has " + std::to_string(info.sizes[slot]) +
                       " entries, but " + file + " has " + std::to_string(rows) + " rows");
}

Material read_material(const fs::path& dir, const MaterialLine& line, const MaterialInfo& info, size_t p4_rows) {
  const auto idx = read_matrix<int64_t>(dir, line.name + "_PDF6Dslices.txt");
  const auto scale = read_matrix<float>(dir, line.name + "_PDF6Dscale.txt");
  if (idx.rows != size_t(line.rows) || idx.cols != size_t(line.cols))
    throw CorruptError(idx.file + " line 1: " + std::to_string(idx.rows) + " x " + std::to_string(idx.cols) + ", but " +
                       kInfo + " gives material '" + line.name + "' " + std::to_string(line.rows) + " x " +
                       std::to_string(line.cols));
  expect_same_shape(idx, scale);
  Material m;
  m.name = line.name;
  m.width = line.cols;
  m.height = line.rows;
  m.dynamic = line.hdr_value != 0 ? Dynamic::HDR : Dynamic::LDR;
  const uint64_t channels = uint64_t(line.rows) * uint64_t(line.cols) * uint64_t(info.n_views) * uint64_t(info.n_lights) * 3;
  m.raw_bytes = m.dynamic == Dynamic::LDR ? channels : channels * 3 / 2;
  m.p6_index.resize(idx.data.size());
  for (size_t r = 0; r < idx.rows; ++r)
    for (size_t c = 0; c < idx.cols; ++c) {
      const int64_t v = idx.at(r, c);  // stored plus one; 0 = texel not compressed
      if (v < 0 || uint64_t(v) > p4_rows)
        throw CorruptError(idx.file + " row " + std::to_string(r) + " (line " + std::to_string(r + 2) + ") column " +
                           std::to_string(c) + ": index " + std::to_string(v) + " (1-based) " +
                           (v < 0 ? "is negative" : "> " + std::to_string(p4_rows) + " entries of all_PDF4Dslices.txt"));
      m.p6_index[r * idx.cols + c] = int32_t(v - 1);
    }
  m.p6_scale = scale.data;
  return m;
}

// ---------------------------------------------------------------------------------------------
// Writing

template <class T>
void append_number(std::string& out, T v) {
  char buf[64];
  auto [q, ec] = std::to_chars(buf, buf + sizeof buf, v);  // shortest form that reads back identically
  (void)ec;
  out.append(buf, q);
}

template <class T>
void write_matrix(const fs::path& path, size_t rows, size_t cols, const T* data, T offset = T(0)) {
  std::string out;
  out.reserve(rows * cols * 10 + 64);
  T lo = T(0), hi = T(0);
  if (rows * cols != 0) {
    const auto [mn, mx] = std::minmax_element(data, data + rows * cols);
    lo = *mn + offset;
    hi = *mx + offset;
  }
  append_number(out, rows);
  out += ' ';
  append_number(out, cols);
  out += ' ';
  append_number(out, lo);
  out += ' ';
  append_number(out, hi);
  out += '\n';
  for (size_t r = 0; r < rows; ++r) {
    for (size_t c = 0; c < cols; ++c) {
      if constexpr (std::is_integral_v<T>) append_number(out, T(data[r * cols + c] + offset));
      else append_number(out, data[r * cols + c]);
      out += ' ';  // the original writes a blank after every value
    }
    out += '\n';
  }
  std::ofstream f(path, std::ios::binary);
  f.write(out.data(), std::streamsize(out.size()));
  f.close();
  if (!f) throw InputError("cannot write " + path.string());
}

// An empty, default-constructed table has no columns yet; the file still declares the grid's.
template <class T>
void write_table(const fs::path& dir, const char* file, const Table<T>& t, int cols) {
  write_matrix(dir / file, t.rows(), t.rows() ? t.cols() : size_t(cols), t.data().data());
}

template <class T>
void check_table_cols(const Table<T>& t, int cols, const char* name) {
  if (t.rows() > 0 && t.cols() != size_t(cols))
    throw InputError(std::string("code-book ") + name + " has " + std::to_string(t.cols()) + " columns, the grid needs " +
                     std::to_string(cols));
}

void write_text(const fs::path& path, const std::string& text) {
  std::ofstream f(path, std::ios::binary);
  f << text;
  f.close();
  if (!f) throw InputError("cannot write " + path.string());
}

std::string material_line(const Material& m) {
  return m.name + " ./indata/" + m.name + "/ ./outdata/" + m.name + "/ ./tmp/" + m.name + "/ 0 0 " +
         std::to_string(m.height) + " " + std::to_string(m.width) + (m.dynamic == Dynamic::HDR ? " 1.000000" : " 0.000000");
}

void check_exportable(const Database& db) {
  const Codebooks& k = db.codebooks;
  const AngularGrid& g = k.grid;
  g.validate();
  check_table_cols(k.p1, g.n_beta, "P1");
  check_table_cols(k.c, 2, "C");
  check_table_cols(k.i1, g.n_beta, "I1");
  check_table_cols(k.i2, g.n_alpha, "I2");
  check_table_cols(k.p2_index, g.n_alpha, "P2");
  check_table_cols(k.p2_scale, g.n_alpha, "P2 scale");
  check_table_cols(k.m, 2, "M");
  check_table_cols(k.p3_index, g.n_theta_v, "P3");
  check_table_cols(k.p3_scale, g.n_theta_v, "P3 scale");
  check_table_cols(k.p4_index, g.n_phi_v, "P4");
  check_table_cols(k.p4_scale, g.n_phi_v, "P4 scale");
  if (k.p2_scale.rows() != k.p2_index.rows() || k.p3_scale.rows() != k.p3_index.rows() ||
      k.p4_scale.rows() != k.p4_index.rows())
    throw InputError("code-book index and scale tables of P2, P3 or P4 differ in length");
  db.validate();
  for (size_t i = 0; i < db.materials.size(); ++i) {
    const std::string& n = db.materials[i].name;
    const bool bad = n.empty() || n == "all" || n.find_first_of(" \t\r\n/\\") != std::string::npos;
    if (bad) throw InputError("material name '" + n + "' cannot be written as a BTFBASE file name");
    for (size_t j = 0; j < i; ++j)
      if (db.materials[j].name == n) throw InputError("material name '" + n + "' appears twice");
  }
}

void write_all(const Database& db, const fs::path& dir, const std::string& base) {
  const Codebooks& k = db.codebooks;
  const AngularGrid& g = k.grid;
  write_table(dir, "all_PDF1Dslice.txt", k.p1, g.n_beta);
  write_table(dir, "all_colors.txt", k.c, 2);
  write_table(dir, "all_indexAB.txt", k.i1, g.n_beta);
  write_table(dir, "all_PDF2Dcolours.txt", k.i2, g.n_alpha);
  write_table(dir, "all_PDF2Dslices.txt", k.p2_index, g.n_alpha);
  write_table(dir, "all_PDF2Dscale.txt", k.p2_scale, g.n_alpha);
  write_table(dir, "all_PDF2Dindices.txt", k.m, 2);
  write_table(dir, "all_PDF3Dslices.txt", k.p3_index, g.n_theta_v);
  write_table(dir, "all_PDF3Dscale.txt", k.p3_scale, g.n_theta_v);
  write_table(dir, "all_PDF4Dslices.txt", k.p4_index, g.n_phi_v);
  write_table(dir, "all_PDF4Dscale.txt", k.p4_scale, g.n_phi_v);
  std::ostringstream info;
  const size_t n = db.materials.size();
  info << "./" << base << "/\n" << n << '\n' << std::max<size_t>(n, 1) << "\n1\n0\n0\n2\n81\n81\n32\n";
  info << "1 " << g.n_beta << " 0 " << g.n_alpha << " 0 " << g.n_theta_v << " 0 " << g.n_phi_v << " 0 0 0 0\n";
  info << "0 0 0 0 0 0 0 0 0 0\n";
  info << k.p1.rows() << ' ' << k.c.rows() << ' ' << k.i1.rows() << ' ' << k.m.rows() << ' ' << k.p2_index.rows() << ' '
       << k.i2.rows() << ' ' << k.p3_index.rows() << " 0 " << k.p4_index.rows() << " 0\n";
  info << "2 0 0 0 0 0 0 0 0 1 0\n";  // thresholds: not part of the in-memory database
  for (const auto& m : db.materials) {
    info << material_line(m) << '\n';
    const size_t w = size_t(m.width), h = size_t(m.height);
    write_matrix(dir / (m.name + "_PDF6Dslices.txt"), h, w, m.p6_index.data(), int32_t(1));
    write_matrix(dir / (m.name + "_PDF6Dscale.txt"), h, w, m.p6_scale.data());
    write_text(dir / (m.name + "_materialInfo.txt"), material_line(m) + "\n");
  }
  write_text(dir / kInfo, info.str());
}

}  // namespace

Database import_btfbase(const std::string& dir_name) {
  const fs::path dir(dir_name);
  if (!fs::is_directory(dir)) throw InputError("BTFBASE directory '" + dir_name + "' does not exist");
  const MaterialInfo info = read_material_info(dir);
  Database db;
  db.codebooks = Codebooks(info.grid);
  Codebooks& k = db.codebooks;

  const auto p1 = read_matrix<float>(dir, "all_PDF1Dslice.txt");
  const auto c = read_matrix<float>(dir, "all_colors.txt");
  const auto i1 = read_matrix<int64_t>(dir, "all_indexAB.txt");
  const auto i2 = read_matrix<int64_t>(dir, "all_PDF2Dcolours.txt");
  const auto p2i = read_matrix<int64_t>(dir, "all_PDF2Dslices.txt");
  const auto p2s = read_matrix<float>(dir, "all_PDF2Dscale.txt");
  const auto m = read_matrix<int64_t>(dir, "all_PDF2Dindices.txt");
  const auto p3i = read_matrix<int64_t>(dir, "all_PDF3Dslices.txt");
  const auto p3s = read_matrix<float>(dir, "all_PDF3Dscale.txt");
  const auto p4i = read_matrix<int64_t>(dir, "all_PDF4Dslices.txt");
  const auto p4s = read_matrix<float>(dir, "all_PDF4Dscale.txt");
  expect_same_shape(p2i, p2s);
  expect_same_shape(p3i, p3s);
  expect_same_shape(p4i, p4s);

  check_size(info, 0, "P1", p1.rows, p1.file);
  check_size(info, 1, "C", c.rows, c.file);
  check_size(info, 2, "I1", i1.rows, i1.file);
  check_size(info, 3, "M", m.rows, m.file);
  check_size(info, 4, "P2", p2i.rows, p2i.file);
  check_size(info, 5, "I2", i2.rows, i2.file);
  check_size(info, 6, "P3", p3i.rows, p3i.file);
  check_size(info, 8, "P4", p4i.rows, p4i.file);

  to_float_table(p1, k.p1);
  to_float_table(c, k.c);
  to_index_table(i1, k.i1, c.rows, c.file);
  to_index_table(i2, k.i2, i1.rows, i1.file);
  to_index_table(p2i, k.p2_index, p1.rows, p1.file);
  to_float_table(p2s, k.p2_scale);
  // M: column 0 indexes P2, column 1 indexes I2.
  expect_cols(m, 2, "M (P2 index, I2 index)");
  k.m.resize_rows(m.rows);
  for (size_t r = 0; r < m.rows; ++r)
    for (size_t col = 0; col < 2; ++col) {
      const int64_t v = m.at(r, col);
      const size_t limit = col == 0 ? p2i.rows : i2.rows;
      if (v < 0 || uint64_t(v) >= limit)
        throw CorruptError(index_error(m.file, r, col, v, limit, col == 0 ? p2i.file : i2.file));
      k.m.at(r, col) = uint32_t(v);
    }
  to_index_table(p3i, k.p3_index, m.rows, m.file);
  to_float_table(p3s, k.p3_scale);
  to_index_table(p4i, k.p4_index, p3i.rows, p3i.file);
  to_float_table(p4s, k.p4_scale);

  for (const auto& line : info.materials) {
    for (const auto& prev : db.materials)
      if (prev.name == line.name) throw CorruptError(std::string(kInfo) + ": material '" + line.name + "' is listed twice");
    db.materials.push_back(read_material(dir, line, info, p4i.rows));
  }
  db.validate();  // belt and braces: every index was checked above with its file and row
  return db;
}

void export_btfbase(const Database& db, const std::string& dir_name) {
  check_exportable(db);
  fs::path dir = fs::absolute(fs::path(dir_name)).lexically_normal();
  if (dir.filename().empty()) dir = dir.parent_path();
  std::error_code ec;
  fs::create_directories(dir.parent_path(), ec);
  AtomicFile out(dir.string());
  if (!fs::create_directory(out.temp_path(), ec) || ec)
    throw InputError("cannot create a directory next to '" + dir.string() + "': " + ec.message());
  try {
    write_all(db, out.temp_path(), dir.filename().string());
  } catch (const fs::filesystem_error& e) {
    throw InputError("cannot write BTFBASE directory '" + dir.string() + "': " + e.what());
  }
  out.commit();
}

}  // namespace btfvq
