#!/bin/bash
# A throw-away single-node Slurm (munged + slurmctld + slurmd, all as root) in folder $1, for
# tests/test_slurm.cpp and for trying the Slurm executor by hand (docs/cluster.md).
#   scripts/slurm-single-node.sh start DIR   -> DIR/slurm.conf, DIR/env (SLURM_CONF=...), daemons up
#   scripts/slurm-single-node.sh stop DIR    -> the daemons it started are stopped
# On failure it prints one line saying why and exits 1.
set -u
cmd=${1:-}; dir=${2:-}
[ -n "$cmd" ] && [ -n "$dir" ] || { echo "usage: $0 start|stop DIR"; exit 2; }
fail() { echo "slurm: $*"; exit 1; }

stop() {
  for p in slurmd slurmctld munged; do
    [ -f "$dir/$p.pid" ] || continue
    pid=$(cat "$dir/$p.pid" 2>/dev/null)
    [ -n "$pid" ] && kill "$pid" 2>/dev/null
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -9 "$pid" 2>/dev/null
    rm -f "$dir/$p.pid"
  done
}

if [ "$cmd" = stop ]; then stop; exit 0; fi
[ "$cmd" = start ] || fail "unknown command $cmd"
[ "$(id -u)" = 0 ] || fail "must run as root (slurmd starts job steps as their user)"
for b in munged slurmctld slurmd sbatch squeue scancel; do
  command -v "$b" >/dev/null || fail "$b is not installed (Debian packages slurm-wlm and munge; make deps)"
done
mkdir -p "$dir"/{munge,state,spool,log} || fail "cannot create $dir"
dir=$(cd "$dir" && pwd)
chmod 0755 "$dir"
# munged insists on private folders owned by the user it runs as.
chmod 0700 "$dir/munge"
dd if=/dev/urandom of="$dir/munge/munge.key" bs=1024 count=1 status=none
chmod 0400 "$dir/munge/munge.key"
munged --force --key-file="$dir/munge/munge.key" --socket="$dir/munge/munge.socket" \
  --pid-file="$dir/munged.pid" --log-file="$dir/log/munged.log" --seed-file="$dir/munge/seed" \
  >"$dir/log/munged.out" 2>&1 || fail "munged did not start: $(tail -n1 "$dir/log/munged.log" "$dir/log/munged.out" 2>/dev/null | grep -v '^==' | grep . | tail -n1)"

port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
node=$(hostname -s)
cpus=$(nproc)
mem=$(awk '/MemTotal/ {print int($2/1024/2)}' /proc/meminfo)
cat >"$dir/slurm.conf" <<CONF
ClusterName=btfvqtest
SlurmctldHost=$node(127.0.0.1)
SlurmUser=root
SlurmdUser=root
SlurmctldPort=$(port)
SlurmdPort=$(port)
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge/munge.socket
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MpiDefault=none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
SlurmctldTimeout=30
SlurmdTimeout=30
InactiveLimit=0
MinJobAge=30
KillWait=2
MessageTimeout=10
NodeName=$node NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=btfvq Nodes=$node Default=YES MaxTime=INFINITE State=UP
CONF
echo "SLURM_CONF=$dir/slurm.conf" >"$dir/env"
export SLURM_CONF="$dir/slurm.conf"
slurmctld -c -f "$dir/slurm.conf" >"$dir/log/slurmctld.out" 2>&1 || { stop; fail "slurmctld did not start: $(tail -n1 "$dir/log/slurmctld.log" 2>/dev/null)"; }
slurmd -f "$dir/slurm.conf" >"$dir/log/slurmd.out" 2>&1 || { stop; fail "slurmd did not start: $(grep -i error "$dir/log/slurmd.log" 2>/dev/null | tail -n1)"; }
# Up when the node is idle.
for _ in $(seq 150); do
  state=$(sinfo -h -n "$node" -o %T 2>/dev/null)
  case "$state" in idle*|mixed*|allocated*) echo "slurm: up in $dir (node $node, $cpus CPUs)"; exit 0;; esac
  sleep 0.2
done
why=$(grep -i error "$dir/log/slurmd.log" "$dir/log/slurmctld.log" 2>/dev/null | tail -n1)
stop
fail "slurmd did not come up (node state '${state:-none}'): ${why:-no error logged}"
