#pragma once
// The original authors' "BTFBASE" text databases (docs/btfbase-format.md): one text
// matrix file per code-book ("rows cols min max" header, then rows lines of cols numbers), a
// per-material P6 pair NAME_PDF6Dslices.txt / NAME_PDF6Dscale.txt (indices stored plus one, 0 = texel
// not compressed) and all_materialInfo.txt with the grid, code-book sizes and one line per material.
//
// import_btfbase(export_btfbase(db)) == db for every database that import_btfbase produces; a
// database built by our encoder round-trips too, except raw_bytes, which the text format cannot
// carry and is recomputed as rows x cols x n_views x n_lights x 3 bytes (x 1.5 for HDR).
#include <string>

#include "pipeline/codebook.h"

namespace btfvq {

// Reads a BTFBASE directory. Throws InputError when the directory or a file is missing (naming it),
// CorruptError naming the file and row of the first malformed value or out-of-range index.
Database import_btfbase(const std::string& dir);

// Writes `db` as a BTFBASE directory `dir`. Everything is written into a sibling temporary directory
// that is renamed into place at the end, so `dir` is either absent/unchanged or complete. An existing
// `dir` is replaced. Throws InputError for names the format cannot carry and CorruptError when `db`
// does not validate.
void export_btfbase(const Database& db, const std::string& dir);

}  // namespace btfvq
