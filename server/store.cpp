#include "server/store.h"

#include <sqlite3.h>

#include <cerrno>
#include <cstring>

#include <btfvq/error.h>
#include "pipeline/util/atomic_file.h"

namespace btfvq::server {
namespace {

using nlohmann::json;

// A failed SQLite call as the error the rest of the server knows: a full disk is the NoSpaceError
// of the file writers (SQLite says SQLITE_FULL, or an I/O error whose errno is ENOSPC), so a job
// and an HTTP client see the same "no_space" whichever file it was.
[[noreturn]] void throw_sqlite(sqlite3* db, int rc, const std::string& what) {
  const int err = sqlite3_system_errno(db);
  const std::string message = what + ": " + sqlite3_errmsg(db);
  if ((rc & 0xff) == SQLITE_FULL || is_no_space(err))
    throw NoSpaceError(message + ": " + std::strerror(err == EDQUOT ? EDQUOT : ENOSPC) +
                       (err == EDQUOT ? " (EDQUOT)" : " (ENOSPC)"));
  throw Error("store", message);
}

// A prepared statement with positional binding; finalised on scope exit.
class Statement {
 public:
  Statement(sqlite3* db, const std::string& sql) : db_(db) {
    if (const int rc = sqlite3_prepare_v2(db, sql.c_str(), -1, &stmt_, nullptr); rc != SQLITE_OK)
      throw_sqlite(db, rc, "sqlite prepare of '" + sql + "'");
  }
  ~Statement() { sqlite3_finalize(stmt_); }
  Statement& bind(const std::string& v) {
    sqlite3_bind_text(stmt_, ++n_, v.c_str(), int(v.size()), SQLITE_TRANSIENT);
    return *this;
  }
  Statement& bind(int64_t v) {
    sqlite3_bind_int64(stmt_, ++n_, v);
    return *this;
  }
  Statement& bind(double v) {
    sqlite3_bind_double(stmt_, ++n_, v);
    return *this;
  }
  // Returns true while there is a row.
  bool step() {
    const int rc = sqlite3_step(stmt_);
    if (rc == SQLITE_ROW) return true;
    if (rc == SQLITE_DONE) return false;
    throw_sqlite(db_, rc, "sqlite step of '" + std::string(sqlite3_sql(stmt_)) + "'");
  }
  std::string text(int c) const {
    auto p = sqlite3_column_text(stmt_, c);
    return p ? std::string(reinterpret_cast<const char*>(p)) : std::string();
  }
  int64_t integer(int c) const { return sqlite3_column_int64(stmt_, c); }
  double real(int c) const { return sqlite3_column_double(stmt_, c); }

 private:
  sqlite3* db_;
  sqlite3_stmt* stmt_ = nullptr;
  int n_ = 0;
};

json parse_or_null(const std::string& s) { return s.empty() ? json() : json::parse(s); }

const char* kJobColumns = "id, seq, database, spec, state, progress, error, created, started, finished, version";

JobRecord read_job(const Statement& s) {
  JobRecord j;
  j.id = s.text(0);
  j.seq = s.integer(1);
  j.database = s.text(2);
  j.spec = parse_or_null(s.text(3));
  j.state = parse_job_state(s.text(4));
  j.progress = parse_or_null(s.text(5));
  j.error = parse_or_null(s.text(6));
  j.created = s.real(7);
  j.started = s.real(8);
  j.finished = s.real(9);
  j.version = s.integer(10);
  return j;
}

UploadRecord read_upload(const Statement& s) {
  return {s.text(0), uint64_t(s.integer(1)), s.text(2), s.text(3), s.real(4)};
}

VersionRecord read_version(const Statement& s) {
  return {s.text(0), s.integer(1), s.text(2), s.text(3), uint64_t(s.integer(4)), parse_or_null(s.text(5)),
          s.text(6), s.real(7)};
}

}  // namespace

Store::Store(const std::string& sqlite_path) {
  if (sqlite3_open(sqlite_path.c_str(), &db_) != SQLITE_OK) {
    const std::string message = db_ ? sqlite3_errmsg(db_) : "out of memory";
    sqlite3_close(db_);
    throw Error("store", "cannot open store '" + sqlite_path + "': " + message);
  }
  sqlite3_busy_timeout(db_, 5000);
  exec("PRAGMA journal_mode=WAL");
  exec("PRAGMA synchronous=FULL");
  exec(R"(CREATE TABLE IF NOT EXISTS jobs (
            id TEXT PRIMARY KEY, seq INTEGER NOT NULL UNIQUE, database TEXT NOT NULL, spec TEXT NOT NULL,
            state TEXT NOT NULL, progress TEXT NOT NULL, error TEXT NOT NULL DEFAULT '',
            created REAL NOT NULL, started REAL NOT NULL DEFAULT 0, finished REAL NOT NULL DEFAULT 0,
            version INTEGER NOT NULL DEFAULT 0))");
  exec(R"(CREATE TABLE IF NOT EXISTS uploads (
            id TEXT PRIMARY KEY, size INTEGER NOT NULL, sha256 TEXT NOT NULL, state TEXT NOT NULL,
            created REAL NOT NULL))");
  exec(R"(CREATE TABLE IF NOT EXISTS versions (
            database TEXT NOT NULL, version INTEGER NOT NULL, path TEXT NOT NULL, sha256 TEXT NOT NULL,
            size INTEGER NOT NULL, materials TEXT NOT NULL, job TEXT NOT NULL, created REAL NOT NULL,
            PRIMARY KEY (database, version)))");
}

Store::~Store() { sqlite3_close(db_); }

void Store::exec(const std::string& sql) {
  if (const int rc = sqlite3_exec(db_, sql.c_str(), nullptr, nullptr, nullptr); rc != SQLITE_OK)
    throw_sqlite(db_, rc, "sqlite exec of '" + sql + "'");
}

int64_t Store::insert_job(const JobRecord& j) {
  std::lock_guard lock(mutex_);
  Statement next(db_, "SELECT COALESCE(MAX(seq), 0) + 1 FROM jobs");
  next.step();
  const int64_t seq = next.integer(0);
  Statement s(db_, "INSERT INTO jobs (id, seq, database, spec, state, progress, error, created) VALUES (?,?,?,?,?,?,?,?)");
  s.bind(j.id).bind(seq).bind(j.database).bind(j.spec.dump()).bind(to_string(j.state)).bind(j.progress.dump())
      .bind(j.error.is_null() ? std::string() : j.error.dump(-1, ' ', false, json::error_handler_t::replace)).bind(j.created);
  s.step();
  return seq;
}

std::optional<JobRecord> Store::job(const std::string& id) {
  std::lock_guard lock(mutex_);
  Statement s(db_, std::string("SELECT ") + kJobColumns + " FROM jobs WHERE id = ?");
  s.bind(id);
  if (!s.step()) return std::nullopt;
  return read_job(s);
}

std::vector<JobRecord> Store::jobs() {
  std::lock_guard lock(mutex_);
  Statement s(db_, std::string("SELECT ") + kJobColumns + " FROM jobs ORDER BY seq");
  std::vector<JobRecord> out;
  while (s.step()) out.push_back(read_job(s));
  return out;
}

std::vector<JobRecord> Store::jobs_in_state(JobState state) {
  std::lock_guard lock(mutex_);
  Statement s(db_, std::string("SELECT ") + kJobColumns + " FROM jobs WHERE state = ? ORDER BY seq");
  s.bind(to_string(state));
  std::vector<JobRecord> out;
  while (s.step()) out.push_back(read_job(s));
  return out;
}

void Store::set_job_state(const std::string& id, JobState state, const json& error, double started,
                          double finished) {
  std::lock_guard lock(mutex_);
  Statement s(db_, "UPDATE jobs SET state = ?, error = ?, started = ?, finished = ? WHERE id = ?");
  s.bind(to_string(state)).bind(error.is_null() ? std::string() : error.dump(-1, ' ', false, json::error_handler_t::replace)).bind(started).bind(finished).bind(id);
  s.step();
}

void Store::set_job_progress(const std::string& id, const json& progress) {
  std::lock_guard lock(mutex_);
  Statement s(db_, "UPDATE jobs SET progress = ? WHERE id = ?");
  s.bind(progress.dump(-1, ' ', false, json::error_handler_t::replace)).bind(id);
  s.step();
}

std::vector<std::string> Store::requeue_running() {
  std::lock_guard lock(mutex_);
  std::vector<std::string> ids;
  {
    Statement s(db_, "SELECT id FROM jobs WHERE state = ? ORDER BY seq");
    s.bind(to_string(JobState::running));
    while (s.step()) ids.push_back(s.text(0));
  }
  Statement s(db_, "UPDATE jobs SET state = ?, started = 0, progress = '{}' WHERE state = ?");
  s.bind(to_string(JobState::queued)).bind(to_string(JobState::running));
  s.step();
  return ids;
}

void Store::insert_upload(const UploadRecord& u) {
  std::lock_guard lock(mutex_);
  Statement s(db_, "INSERT OR REPLACE INTO uploads (id, size, sha256, state, created) VALUES (?,?,?,?,?)");
  s.bind(u.id).bind(int64_t(u.size)).bind(u.sha256).bind(u.state).bind(u.created);
  s.step();
}

std::optional<UploadRecord> Store::upload(const std::string& id) {
  std::lock_guard lock(mutex_);
  Statement s(db_, "SELECT id, size, sha256, state, created FROM uploads WHERE id = ?");
  s.bind(id);
  if (!s.step()) return std::nullopt;
  return read_upload(s);
}

std::vector<UploadRecord> Store::uploads() {
  std::lock_guard lock(mutex_);
  Statement s(db_, "SELECT id, size, sha256, state, created FROM uploads ORDER BY created, id");
  std::vector<UploadRecord> out;
  while (s.step()) out.push_back(read_upload(s));
  return out;
}

void Store::publish(const VersionRecord& v, double finished) {
  std::lock_guard lock(mutex_);
  exec("BEGIN IMMEDIATE");
  try {
    Statement s(db_, "INSERT INTO versions (database, version, path, sha256, size, materials, job, created) "
                     "VALUES (?,?,?,?,?,?,?,?)");
    s.bind(v.database).bind(v.version).bind(v.path).bind(v.sha256).bind(int64_t(v.size)).bind(v.materials.dump())
        .bind(v.job).bind(v.created);
    s.step();
    Statement j(db_, "UPDATE jobs SET state = ?, error = '', finished = ?, version = ? WHERE id = ?");
    j.bind(to_string(JobState::succeeded)).bind(finished).bind(v.version).bind(v.job);
    j.step();
    exec("COMMIT");
  } catch (...) {
    // SQLite may have rolled back by itself (it does on SQLITE_FULL); the error to report is the first.
    if (!sqlite3_get_autocommit(db_)) sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
    throw;
  }
}

std::vector<VersionRecord> Store::versions(const std::string& database) {
  std::lock_guard lock(mutex_);
  Statement s(db_, "SELECT database, version, path, sha256, size, materials, job, created FROM versions "
                   "WHERE database = ? ORDER BY version");
  s.bind(database);
  std::vector<VersionRecord> out;
  while (s.step()) out.push_back(read_version(s));
  return out;
}

std::vector<std::string> Store::database_names() {
  std::lock_guard lock(mutex_);
  Statement s(db_, "SELECT DISTINCT database FROM versions ORDER BY database");
  std::vector<std::string> out;
  while (s.step()) out.push_back(s.text(0));
  return out;
}

std::vector<std::string> Store::all_version_paths() {
  std::lock_guard lock(mutex_);
  Statement s(db_, "SELECT path FROM versions");
  std::vector<std::string> out;
  while (s.step()) out.push_back(s.text(0));
  return out;
}

}  // namespace btfvq::server
