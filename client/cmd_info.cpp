// `btfvq info PATH`: what a file holds, without decoding it: a database (.btfdb magic) or a sample
// (a directory or a zip of UBO2003 images).
#include <iostream>
#include <ostream>
#include <string>

#include "client/cli.h"
#include "pipeline/format/database.h"
#include <btfvq/error.h>
#include "pipeline/io/sample_io.h"

namespace btfvq::cli {
namespace {

std::string with_thousands(uint64_t n) {
  std::string digits = std::to_string(n), out;
  for (size_t i = 0; i < digits.size(); ++i) {
    if (i > 0 && (digits.size() - i) % 3 == 0) out += ',';
    out += digits[i];
  }
  return out;
}

void print_sample_info(std::ostream& out, const std::string& path, const SampleInfo& info) {
  out << "sample:     " << path << "\n";
  out << "size:       " << info.width << " x " << info.height << "\n";
  out << "directions: " << info.views << " views x " << info.lights_per_view << " lights\n";
  out << "dynamic:    " << (info.dynamic == Dynamic::HDR ? "HDR (linear float)" : "LDR (8-bit sRGB-encoded)") << "\n";
  out << "images:     " << info.images << "\n";
  out << "raw bytes:  " << with_thousands(info.raw_bytes) << "\n";
}

void print_database_info(std::ostream& out, const std::string& path, const DatabaseInfo& info) {
  const DatabaseHead& h = info.head;
  uint64_t raw = 0;
  for (const auto& m : info.materials) raw += m.raw_bytes;
  out << "database:   " << path << "\n";
  out << "version:    " << h.version << " (format " << h.format_version << ")\n";
  out << "grid:       n_beta " << h.grid.n_beta << ", n_alpha " << h.grid.n_alpha << ", n_theta_v " << h.grid.n_theta_v
      << ", n_phi_v " << h.grid.n_phi_v << "\n";
  out << "bytes:      " << with_thousands(h.file_size) << " (header and table " << with_thousands(h.head_length) << ")\n";
  if (h.file_size > 0 && raw > 0) out << "ratio:      1:" << double(raw) / double(h.file_size) << "\n";
  out << "code-books: (entries, bytes in the file)\n";
  for (int i = 0; i < kCodebookCount; ++i)
    out << "  " << codebook_name(CodebookId(i)) << "\t" << info.codebook_rows[CodebookId(i)] << "\t"
        << with_thousands(info.codebook_bytes[i]) << "\n";
  out << "materials:  " << info.materials.size() << "\n";
  for (const auto& m : info.materials)
    out << "  " << m.name << "\t" << m.width << " x " << m.height << "\t" << (m.dynamic == Dynamic::HDR ? "HDR" : "LDR")
        << "\tversion " << m.version << "\tP6 " << with_thousands(m.section_bytes) << " bytes\traw "
        << with_thousands(m.raw_bytes) << "\n";
  out << "sections:   " << h.sections.size() << "\n";
  for (const auto& s : h.sections)
    out << "  v" << s.version << "\t" << (s.kind == SectionKind::Material ? "material " + s.material : codebook_name(s.codebook))
        << "\toffset " << s.offset << "\t" << with_thousands(s.length) << " bytes" << (s.encoding == 1 ? " (zstd)" : s.encoding == 2 ? " (range coded)" : "")
        << "\n";
}

int run_info(const Args& args) {
  if (args.positional.size() != 1) throw InputError("usage: btfvq info PATH");
  const std::string& path = args.positional[0];
  if (is_database_file(path)) {
    print_database_info(std::cout, path, inspect_database(path));
    return 0;
  }
  if (is_sample_path(path)) {
    print_sample_info(std::cout, path, inspect_sample(path));
    return 0;
  }
  throw InputError(path + " is neither a btfvq database nor a BTF sample (a directory or zip of UBO2003 images)");
}

CommandRegistrar reg({"info", "info PATH", "describe a database (materials, code-book sizes, bytes per section) or a sample (size, directions, raw bytes)",
                      {}, {}, run_info});

}  // namespace
}  // namespace btfvq::cli
