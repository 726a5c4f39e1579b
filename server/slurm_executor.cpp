#include "server/slurm_executor.h"

#include <fcntl.h>
#include <spawn.h>
#include <spdlog/spdlog.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <thread>

#include <btfvq/error.h>
#include "pipeline/encode/tile_parts.h"
#include "pipeline/util/atomic_file.h"

extern char** environ;

namespace btfvq::server {
namespace fs = std::filesystem;

namespace {

struct Output {
  int status = -1;   // exit status, -1 when it could not run
  std::string text;  // stdout and stderr
};

// Runs a Slurm command (no shell: arguments as they are), its output collected.
Output run_command(const std::vector<std::string>& argv) {
  Output out;
  int pipe_fds[2];
  if (::pipe2(pipe_fds, O_CLOEXEC) != 0) return out;
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, pipe_fds[1], 1);
  posix_spawn_file_actions_adddup2(&actions, pipe_fds[1], 2);
  std::vector<char*> args;
  for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  pid_t pid = 0;
  const int rc = posix_spawnp(&pid, args[0], &actions, nullptr, args.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  ::close(pipe_fds[1]);
  if (rc != 0) {
    ::close(pipe_fds[0]);
    out.text = argv[0] + ": " + std::strerror(rc);
    return out;
  }
  char buffer[4096];
  for (ssize_t n; (n = ::read(pipe_fds[0], buffer, sizeof buffer)) != 0;) {
    if (n < 0) {
      if (errno == EINTR) continue;
      break;
    }
    out.text.append(buffer, size_t(n));
  }
  ::close(pipe_fds[0]);
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  out.status = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return out;
}

std::string one_line(std::string s) {
  std::replace(s.begin(), s.end(), '\n', ' ');
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s;
}

std::string quoted(const std::string& s) {  // for /bin/sh, in single quotes
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

std::string default_tile_command() {
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  if (!ec && fs::exists(self.parent_path() / "btfvq")) return (self.parent_path() / "btfvq").string();
  return "btfvq";
}

// Phase 3 of one material on the cluster.
class SlurmPhaseThree {
 public:
  SlurmPhaseThree(const SlurmSettings& s, const JobSpec& spec, JobContext& ctx, const PhaseThreeWork& w)
      : s_(s), spec_(spec), ctx_(ctx), w_(w) {
    dir_ = fs::path(s.shared_folder) / ("job-" + spec.id) / ("input-" + std::to_string(w.input));
    name_ = "btfvq-" + spec.id + "-" + std::to_string(w.input);
  }

  void run() {
    std::error_code ec;
    fs::create_directories(dir_, ec);
    if (ec) throw InputError("the Slurm shared folder: cannot create " + dir_.string() + ": " + ec.message());
    write_raw_sample(*w_.sample, (dir_ / "sample.raw").string());
    write_script();
    size_t merged = w_.tiles_done, p4 = w_.p4_rows;
    const size_t per = size_t(std::max(1, s_.tiles_per_element));
    size_t width = std::numeric_limits<size_t>::max();
    w_.progress(merged);
    try {
      for (int wave = 1; merged < w_.tiles; ++wave) {
        const fs::path snap = dir_ / ("wave-" + std::to_string(wave));
        const size_t snap_p4 = write_tile_snapshot(w_, snap.string());
        if (snap_p4 != p4) throw Error("internal", "the tile snapshot holds other P4 rows than merged");
        // Speculation width: elements after the first are computed from the snapshot's code-books and
        // are stale once an earlier tile composes P4 rows. All of them in the first wave (a material
        // that composes nothing finishes in one); after a stale wave as many as were good, doubled
        // after a wave without one, so a material that composes in every tile costs about 1.5
        // element runs per tile, not one per remaining tile.
        const size_t base = merged, groups = std::min(width, (w_.tiles - merged + per - 1) / per);
        std::vector<std::string> element(groups);  // the Slurm id ("J_i") of each element's latest run
        std::vector<int> attempts(groups, 0);
        const std::string job = submit(snap, base, per, "0-" + std::to_string(groups - 1));
        for (size_t i = 0; i < groups; ++i) element[i] = job + "_" + std::to_string(i);
        const size_t last = std::min(w_.tiles, base + groups * per) - 1;
        spdlog::info("job {}: phase-3 tiles {}-{} of {} of '{}' as Slurm array {} ({} elements, wave {})", spec_.id, base,
                     last, w_.tiles, w_.material, job, groups, wave);
        size_t next = 0;  // the element merged next
        bool stale = false;
        while (next < groups && !stale) {
          if (ctx_.cancelled()) throw CancelledError("cancelled by request");
          // squeue may fail for a moment (slurmctld restarting): then nothing is resubmitted this round.
          std::optional<std::set<std::string>> active;
          try {
            active = listed();
            squeue_failures_ = 0;
          } catch (const Error& e) {
            if (++squeue_failures_ > 30) throw;
            spdlog::warn("job {}: {} (will ask again)", spec_.id, e.what());
          }
          // In tile order: a finished part either continues the merged code-books or is stale.
          while (next < groups) {
            const std::string part = (snap / ("part-" + std::to_string(next))).string();
            if (!fs::exists(part + ".json")) break;
            TilePart p;
            try {
              p = check_tile_part(part);
            } catch (const CorruptError& e) {
              spdlog::warn("job {}: {}", spec_.id, e.what());
              fs::remove(part + ".json", ec);
              break;  // resubmitted below once Slurm no longer runs it
            }
            if (p.first != base + next * per) throw Error("internal", "tile part " + part + " of other tiles");
            if (p.p4_from != p4) {  // an earlier tile composed P4 rows this part did not see
              stale = true;
              break;
            }
            merge_tile_part(w_, part);
            merged = p.end;
            p4 = p.p4_end;
            timings_.push_back({p.load_seconds, p.seconds, p.end - p.first});
            ++next;
            w_.progress(merged);
          }
          if (stale) break;
          for (size_t i = next; active && i < groups; ++i) {
            if (active->count(element[i]) || fs::exists(snap / ("part-" + std::to_string(i) + ".json"))) continue;
            if (++attempts[i] > s_.max_resubmits)
              throw Error("slurm", "Slurm element " + element[i] + " (tiles " + std::to_string(base + i * per) +
                                       "-) ended without its part " + std::to_string(attempts[i]) +
                                       " times; see " + (snap / ("slurm-" + element[i] + ".out")).string());
            const std::string again = submit(snap, base, per, std::to_string(i));
            spdlog::warn("job {}: Slurm element {} ended without its part: resubmitted as {}_{} (attempt {})",
                         spec_.id, element[i], again, i, attempts[i] + 1);
            element[i] = again + "_" + std::to_string(i);
            ++resubmitted_;
          }
          if (next < groups) std::this_thread::sleep_for(std::chrono::duration<double>(s_.poll_interval_s));
        }
        width = stale ? std::max<size_t>(1, next) : (width > groups ? width : 2 * width);
        if (stale) {
          spdlog::info("job {}: tiles from {} of '{}' were computed before tile {} composed P4 rows: again from a new snapshot",
                       spec_.id, merged, w_.material, merged - 1);
          cancel_all();
        }
        fs::remove_all(snap, ec);
      }
    } catch (...) {
      cancel_all();
      throw;
    }
    cancel_all();
    fs::remove_all(dir_, ec);
    double load = 0, tiles = 0;
    size_t n = 0;
    for (const auto& t : timings_) load += t.load, tiles += t.seconds, n += t.tiles;
    spdlog::info("job {}: phase 3 of '{}' on Slurm: {} tiles, {} resubmitted element(s), per merged element load {:.2f} s, "
                 "per tile {:.3f} s", spec_.id, w_.material, n, resubmitted_, timings_.empty() ? 0.0 : load / double(timings_.size()),
                 n ? tiles / double(n) : 0.0);
  }

 private:
  struct Timing {
    double load, seconds;
    size_t tiles;
  };

  void write_script() {
    const std::string cmd = s_.tile_command.empty() ? default_tile_command() : s_.tile_command;
    std::ostringstream sh;
    sh << "#!/bin/sh\n"
       << "# btfvq job " << spec_.id << ", material " << w_.material << ": one array element = phase-3 tiles\n"
       << "# args: BASE PER LAST SNAPSHOT\n"
       << "set -e\n"
       << "a=$(($1 + SLURM_ARRAY_TASK_ID * $2)); b=$((a + $2 - 1)); [ $b -le $3 ] || b=$3\n"
       << "exec " << quoted(cmd) << " tile --codebooks \"$4\" --sample " << quoted((dir_ / "sample.raw").string())
       << " --tiles \"$a-$b\" --out \"$4/part-$SLURM_ARRAY_TASK_ID\"\n";
    write_file_atomically((dir_ / "tile.sh").string(), sh.str());
    fs::permissions(dir_ / "tile.sh", fs::perms::owner_all | fs::perms::group_read | fs::perms::others_read);
  }

  // sbatch --array=ARRAY: the Slurm job id.
  std::string submit(const fs::path& snap, size_t base, size_t per, const std::string& array) {
    std::vector<std::string> argv = {"sbatch", "--parsable", "--job-name=" + name_, "--array=" + array,
                                     "--output=" + (snap / "slurm-%A_%a.out").string(), "--chdir=" + dir_.string(),
                                     "--cpus-per-task=" + std::to_string(cpus())};
    if (!s_.partition.empty()) argv.push_back("--partition=" + s_.partition);
    std::istringstream extra(s_.sbatch_options);
    for (std::string o; extra >> o;) argv.push_back(o);
    argv.insert(argv.end(), {(dir_ / "tile.sh").string(), std::to_string(base), std::to_string(per),
                             std::to_string(w_.tiles - 1), snap.string()});
    // Like squeue, sbatch fails while slurmctld is busy or restarting: asked again a few times
    // (about 10 s in all) before the job fails.
    for (int attempt = 1;; ++attempt) {
      const Output o = run_command(argv);
      std::string id = one_line(o.text);
      if (const auto semi = id.find(';'); semi != std::string::npos) id.resize(semi);  // "ID;CLUSTER"
      if (o.status == 0 && !id.empty() && id.find_first_not_of("0123456789") == std::string::npos) {
        jobs_.insert(id);
        return id;
      }
      if (attempt == 5 || ctx_.cancelled()) throw Error("slurm", "sbatch failed: " + one_line(o.text));
      spdlog::warn("job {}: sbatch failed ({}): will try again", spec_.id, one_line(o.text));
      std::this_thread::sleep_for(std::chrono::seconds(attempt));
    }
  }

  int cpus() const {
    if (s_.cpus_per_element > 0) return s_.cpus_per_element;
    const nlohmann::json& threads = w_.config.value("/schedule/threads"_json_pointer, nlohmann::json(1));
    return threads.is_number_integer() ? std::max(1, threads.get<int>()) : 1;
  }

  // The array elements Slurm still lists (pending, running, completing) under this material's name.
  std::set<std::string> listed() {
    const Output o = run_command({"squeue", "--noheader", "--array", "--name=" + name_, "--format=%i"});
    if (o.status != 0) throw Error("slurm", "squeue failed: " + one_line(o.text));
    std::set<std::string> ids;
    std::istringstream in(o.text);
    for (std::string id; in >> id;) ids.insert(id);
    return ids;
  }

  // scancel every Slurm job of this material, then wait until squeue no longer lists them.
  void cancel_all() {
    if (jobs_.empty()) return;
    std::vector<std::string> argv = {"scancel"};
    argv.insert(argv.end(), jobs_.begin(), jobs_.end());
    run_command(argv);
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (std::chrono::steady_clock::now() < until) {
      try {
        if (listed().empty()) break;
      } catch (const Error& e) {
        spdlog::warn("job {}: {}", spec_.id, e.what());
        break;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
    jobs_.clear();
  }

  const SlurmSettings& s_;
  const JobSpec& spec_;
  JobContext& ctx_;
  const PhaseThreeWork& w_;
  fs::path dir_;
  std::string name_;
  std::set<std::string> jobs_;  // every Slurm job id submitted and not yet cancelled
  std::vector<Timing> timings_;
  size_t resubmitted_ = 0;
  int squeue_failures_ = 0;  // in a row
};

}  // namespace

Executor make_slurm_executor(SlurmSettings settings) {
  if (settings.shared_folder.empty()) throw ConfigError("executor \"slurm\" needs slurm.shared_folder");
  auto remote = [settings](const JobSpec& spec, JobContext& ctx, const PhaseThreeWork& w) {
    SlurmPhaseThree(settings, spec, ctx, w).run();
  };
  Executor inner = make_pipeline_executor(remote);
  return [inner, settings](const JobSpec& spec, const std::string& previous, const std::string& out, JobContext& ctx) {
    struct Cleanup {  // the job's folder in the shared one, whatever happens
      fs::path dir;
      ~Cleanup() {
        std::error_code ec;
        fs::remove_all(dir, ec);
      }
    } cleanup{fs::path(settings.shared_folder) / ("job-" + spec.id)};
    inner(spec, previous, out, ctx);
  };
}

}  // namespace btfvq::server
