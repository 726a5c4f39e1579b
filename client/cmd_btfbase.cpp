// `btfvq import-btfbase` and `btfvq export-btfbase`: the original authors' text databases.
#include <iostream>

#include "client/cli.h"
#include "pipeline/io/btfbase.h"
#include "pipeline/format/database.h"

namespace btfvq::cli {
namespace {

int run_import(const Args& a) {
  if (a.positional.size() != 1) throw InputError("usage: btfvq import-btfbase DIR --db OUT.btfdb");
  const Database db = import_btfbase(a.positional[0]);
  // Lossless: an imported database must decode to exactly the values the original decoder gives.
  write_database(db, a.require("db"), PackSettings::lossless());
  std::cout << "imported " << db.materials.size() << " material(s) into " << a.require("db") << "\n";
  return 0;
}

int run_export(const Args& a) {
  if (a.positional.size() != 1) throw InputError("usage: btfvq export-btfbase DB --out DIR");
  export_btfbase(read_database(a.positional[0]), a.require("out"));
  std::cout << "exported to " << a.require("out") << "\n";
  return 0;
}

CommandRegistrar import_reg({"import-btfbase", "import-btfbase DIR --db OUT.btfdb",
                             "import an original MLVQ (BTFBASE text) database, losslessly",
                             {{"db", "OUT.btfdb", "the database to write"}}, {}, run_import});
CommandRegistrar export_reg({"export-btfbase", "export-btfbase DB --out DIR",
                             "write a database in the original MLVQ (BTFBASE text) format",
                             {{"out", "DIR", "the folder to write"}}, {}, run_export});

}  // namespace
}  // namespace btfvq::cli
