#!/usr/bin/env bash
# Runs every benchmark program and rewrites BENCHMARKS.md and bench/results/latest.json.
# Usage: bash bench/run.sh BIN_DIR [BENCH ARGS...]   (make bench builds a -O3 -march=native release
# first; `make bench BENCH_ARGS=--quick` runs smaller sizes, and BENCHMARKS.md says so)
# bench_rate_distortion also reads BTFVQ_RD_ARGS (its own flags: --presets, --size, --big, --proposte,
# --scales, --pca, --grouped, --lab, --vq; see the top of bench/bench_rate_distortion.cpp), e.g.
#   BTFVQ_RD_ARGS="--presets tile,wood --big none" make bench
set -euo pipefail
bin=${1:-build-release/bin}
shift || true
extra=("$@")
root=$(cd "$(dirname "$0")/.." && pwd)
work=$(mktemp -d /tmp/btfvq-bench.XXXXXX)
trap 'rm -rf "$work"' EXIT
mkdir -p "$root/bench/results"
for b in "$bin"/bench_*; do
  [ -x "$b" ] || continue
  name=$(basename "$b")
  echo "== $name" >&2
  "$b" --json "$work/$name.json" --scratch "$work/$name.scratch" --testdata "$root/../shared/testdata" \
       --figures "$root/bench/results" "${extra[@]}" >&2
done
python3 "$root/bench/report.py" --results "$work" --out "$root/BENCHMARKS.md" --json "$root/bench/results/latest.json" \
  --command "make bench${extra:+ BENCH_ARGS=\"${extra[*]}\"}"
echo "wrote BENCHMARKS.md and bench/results/latest.json" >&2
