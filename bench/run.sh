#!/usr/bin/env bash
# Runs every benchmark program and rewrites BENCHMARKS.md and bench/results/latest.json.
# Usage: bash bench/run.sh BIN_DIR [BENCH ARGS...]   (make bench builds a -O3 -march=native release
# first; `make bench BENCH_ARGS=--quick` runs smaller sizes, and BENCHMARKS.md says so)
# bench_rate_distortion also reads BTFVQ_RD_ARGS (its own flags: --presets, --size, --big, --proposte,
# --qualities, --phase2, --pca, --grouped, --lab, --vq, --btf-cielab; see the top of bench/bench_rate_distortion.cpp), e.g.
#   BTFVQ_RD_ARGS="--presets tile,wood --big none" make bench
set -euo pipefail
bin=${1:-build-release/bin}
shift || true
extra=("$@")
root=$(cd "$(dirname "$0")/.." && pwd)
# Every program's section is kept in bench/results/sections/ with its own provenance (commit, date,
# arguments), so that a long benchmark can be re-run alone: BENCH_ONLY="bench_compression" make bench
# re-runs that program and re-assembles BENCHMARKS.md from all kept sections.
sections="$root/bench/results/sections"
mkdir -p "$sections"
work=$(mktemp -d /tmp/btfvq-bench.XXXXXX)
trap 'rm -rf "$work"' EXIT
commit=$(cd "$root" && git rev-parse --short HEAD 2>/dev/null || echo unknown)
if [ -n "$(cd "$root" && git status --porcelain --untracked-files=no -- . ':!BENCHMARKS.md' ':!bench/results' 2>/dev/null)" ]; then commit="$commit (dirty)"; fi
# A bench that keeps results of its own (bench_rate_distortion) records which run measured them.
export BTFVQ_BENCH_COMMIT="$commit"
export BTFVQ_BENCH_COMMAND="make bench${extra:+ BENCH_ARGS=\"${extra[*]}\"}${BENCH_ONLY:+ (BENCH_ONLY=$BENCH_ONLY)}"
# The programs, and the scripts that compare whole command lines (bench/bench_*.sh: they get the
# folder of the programs as --bin).
for b in "$bin"/bench_* "$root"/bench/bench_*.sh; do
  [ -x "$b" ] || continue
  name=$(basename "$b" .sh)
  if [ -n "${BENCH_ONLY:-}" ] && [[ ",${BENCH_ONLY// /,}," != *",$name,"* ]]; then continue; fi
  echo "== $name" >&2
  script=(); [[ "$b" == *.sh ]] && script=(--bin "$bin")
  "$b" "${script[@]}" --json "$work/$name.json" --scratch "$work/$name.scratch" --testdata "$root/tests/data" \
       --figures "$root/bench/results" "${extra[@]}" >&2
  python3 - "$work/$name.json" "$sections/$name.json" "$commit" "make bench${extra:+ BENCH_ARGS=\"${extra[*]}\"}" <<'PY'
import datetime, json, sys
src, dst, commit, command = sys.argv[1:5]
with open(src) as fh:
    s = json.load(fh)
s["provenance"] = {"commit": commit, "command": command,
                   "date": datetime.datetime.utcnow().strftime("%Y-%m-%d %H:%M UTC")}
with open(dst, "w") as fh:
    json.dump(s, fh, indent=1)
PY
done
python3 "$root/bench/report.py" --results "$sections" --out "$root/BENCHMARKS.md" --json "$root/bench/results/latest.json" --commit "$commit" \
  --command "make bench${extra:+ BENCH_ARGS=\"${extra[*]}\"}${BENCH_ONLY:+ (BENCH_ONLY=$BENCH_ONLY)}"
echo "wrote BENCHMARKS.md and bench/results/latest.json" >&2
