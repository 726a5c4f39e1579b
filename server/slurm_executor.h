#pragma once
// The Slurm executor (configs/server.json "executor": "slurm"; docs/cluster.md): the pipeline
// executor with phase 3 of every material on a Slurm cluster. After the growing phases the job
// writes a snapshot of its checkpoint (the frozen code-books) and the sample's texels to the shared
// folder, submits one `sbatch --array` over groups of phase-3 tiles (each element runs
// `btfvq tile`), follows it with squeue, resubmits elements that ended without a checked part up
// to a limit, merges the parts in tile order into the job's checkpoint and lets the compression
// continue from it, so the database is the local executor's byte for byte
// (pipeline/encode/tile_parts.h says why parts may be computed again). Cancelling the job
// scancels its Slurm jobs and waits until squeue no longer lists them.
#include <string>

#include "server/executor.h"

namespace btfvq::server {

struct SlurmSettings {
  std::string partition;       // "" : the cluster's default partition
  std::string shared_folder;   // seen by the server and every node at the same path
  std::string sbatch_options;  // more sbatch options, split at white space (e.g. "--time=30 --account=lab")
  std::string tile_command;    // the btfvq CLI as the nodes run it; "" : "btfvq" next to btfvq-server
  int tiles_per_element = 4;   // phase-3 tiles per array element
  int cpus_per_element = 0;    // sbatch --cpus-per-task; 0: the pipeline's schedule.threads (the tile's search threads)
  int max_resubmits = 3;       // per element, before the job fails
  double poll_interval_s = 1;  // squeue and the parts are looked at this often
};

Executor make_slurm_executor(SlurmSettings settings);

}  // namespace btfvq::server
