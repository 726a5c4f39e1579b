#!/usr/bin/env bash
# Code-book economy, measured as a user meets it: samples as UBO2003 JPEG archives (quality 95), fed
# to `btfvq compress` at default settings and scored by `btfvq eval`, once by this build and once by
# the build of a baseline commit (ff20a73, before the economy work), in the same run.
#   - synthetic leather, wood, fabric at 128 x 128, seeds 1 and 2 (`btfvq synth`);
#   - proposte: the original authors' database (tests/data/btfbase/proposte) imported and decoded
#     to a folder of JPEGs (`btfvq import-btfbase`, `btfvq decode`), as real archives are.
# Usage (by bench/run.sh): bench_economy.sh --bin DIR --json OUT --scratch DIR --testdata DIR [--quick]
# BTFVQ_ECONOMY_BASE (default ff20a73) is built in a git worktree under the scratch folder, or
# BTFVQ_ECONOMY_OLD_BIN names an already built btfvq of it. --quick: seed 1 and no proposte.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
bin="" json="" scratch="" testdata="$root/tests/data" quick=0
while [ $# -gt 0 ]; do
  case "$1" in
    --bin) bin=$2; shift 2 ;;
    --json) json=$2; shift 2 ;;
    --scratch) scratch=$2; shift 2 ;;
    --testdata) testdata=$2; shift 2 ;;
    --figures) shift 2 ;;
    --quick) quick=1; shift ;;
    -h|--help) sed -n 2,11p "$0"; exit 0 ;;
    *) echo "bench_economy: unknown argument '$1'" >&2; exit 2 ;;
  esac
done
[ -n "$bin" ] && [ -n "$json" ] && [ -n "$scratch" ] || { echo "bench_economy: --bin, --json and --scratch are required" >&2; exit 2; }
new="$bin/btfvq"
base=${BTFVQ_ECONOMY_BASE:-ff20a73}
mkdir -p "$scratch"
scratch=$(cd "$scratch" && pwd)

old=${BTFVQ_ECONOMY_OLD_BIN:-}
if [ -z "$old" ]; then
  # The baseline is built from this repository's history, without touching the working tree.
  wt="$scratch/baseline"
  git -C "$root" worktree prune
  [ -d "$wt" ] || git -C "$root" worktree add --detach "$wt" "$base" >&2
  trap 'git -C "$root" worktree remove --force "$wt" 2>/dev/null || true' EXIT
  cmake -S "$wt" -B "$wt/build" -DCMAKE_BUILD_TYPE=Release -DBTFVQ_NATIVE=ON -DBTFVQ_WERROR=OFF -DBTFVQ_TESTS=OFF -DBTFVQ_BENCH=OFF > /dev/null
  cmake --build "$wt/build" --target btfvq-cli -j "$(nproc)" > /dev/null
  old="$wt/build/bin/btfvq"
fi

samples=()
seeds="1 2"; [ $quick = 1 ] && seeds="1"
for seed in $seeds; do
  for preset in leather wood fabric; do
    z="$scratch/${preset}${seed}.zip"
    [ -f "$z" ] || "$new" synth --preset $preset --size 128 --seed $seed --out "$z" > /dev/null
    samples+=("$z")
  done
done
if [ $quick = 0 ]; then
  p="$scratch/proposte"
  if [ ! -d "$p" ]; then
    "$new" import-btfbase "$testdata/btfbase/proposte" --db "$scratch/proposte_original.btfdb" > /dev/null
    "$new" decode "$scratch/proposte_original.btfdb" --material proposte --out "$p" > /dev/null
  fi
  samples+=("$p")
fi

rows="$scratch/rows.jsonl"
: > "$rows"
for s in "${samples[@]}"; do
  name=$(basename "$s" .zip)
  for which in old new; do
    b=$old; [ $which = new ] && b=$new
    out="$scratch/$name.$which"
    echo "bench_economy: $name ($which)" >&2
    start=$(date +%s.%N)
    /usr/bin/time -f "%U %S %e" -o "$out.time" "$b" compress "$s" --db "$out.btfdb" --name m --report "$out.report.json" > "$out.log" 2>&1
    "$new" eval "$out.btfdb" --material m --reference "$s" --json "$out.eval.json" > /dev/null
    python3 - "$name" "$which" "$out" >> "$rows" <<'PY'
import json, sys
name, which, out = sys.argv[1:4]
r = json.load(open(out + ".report.json")); e = json.load(open(out + ".eval.json"))
user, system, wall = map(float, open(out + ".time").read().split()[-3:])
m = r["materials"][0]
print(json.dumps({"sample": name, "build": which, "bytes": r["bytes"], "ratio": r["compression_ratio"],
                  "mssim": e["mssim"], "psnr": e["psnr"], "ciede2000": e["ciede2000_mean"],
                  "entries": m["codebook_sizes"], "cpu_s": user + system, "wall_s": wall}))
PY
  done
done

python3 - "$rows" "$json" "$base" "$quick" <<'PY'
import json, sys
rows_file, out, base, quick = sys.argv[1:5]
rows = [json.loads(l) for l in open(rows_file)]
by = {(r["sample"], r["build"]): r for r in rows}
names = list(dict.fromkeys(r["sample"] for r in rows))
books = ["P1", "C", "I1", "I2", "P2", "M", "P3", "P4"]
md = ["Samples as users have them (UBO2003 JPEG, quality 95) through `btfvq compress` at default settings, "
      f"scored by `btfvq eval` (MSSIM of Y over all images); the baseline is commit {base} (built in a "
      "git worktree, or the binary given by BTFVQ_ECONOMY_OLD_BIN), both measured in this run. "
      "Ratio gain = new ratio / baseline ratio.", "",
      f"| sample | {base} bytes | ratio | MSSIM | new bytes | ratio | MSSIM | ratio gain | MSSIM change | wall s {base} / new |",
      "|---|---|---|---|---|---|---|---|---|---|"]
figures = {}
for n in names:
    o, w = by[(n, "old")], by[(n, "new")]
    gain = w["ratio"] / o["ratio"]
    md.append(f"| {n} | {o['bytes']:,} | 1:{o['ratio']:.0f} | {o['mssim']:.4f} | {w['bytes']:,} | 1:{w['ratio']:.0f} | "
              f"{w['mssim']:.4f} | {gain:.2f}x | {w['mssim'] - o['mssim']:+.4f} | {o['wall_s']:.0f} / {w['wall_s']:.0f} |")
    figures[n] = {"baseline": o, "new": w, "ratio_gain": gain}
md += ["", "Entries per code-book (proposte: the original authors' own database of the same data beside them):", "",
       "| sample | build | " + " | ".join(books) + " | leaves P1+C+I1 |", "|---|---|" + "---|" * (len(books) + 1)]
original = {"P1": 5889, "C": 11, "I1": 6660, "I2": 9965, "P2": 26669, "M": 30919, "P3": 12503, "P4": 786}
for n in names:
    if n == "proposte":
        md.append("| proposte | original (BTFBASE) | " + " | ".join(f"{original[b]:,}" for b in books) +
                  f" | {original['P1'] + original['C'] + original['I1']:,} |")
    for which, label in (("old", base), ("new", "new")):
        e = by[(n, which)]["entries"]
        md.append(f"| {n} | {label} | " + " | ".join(f"{e[b]:,}" for b in books) + f" | {e['P1'] + e['C'] + e['I1']:,} |")
if quick == "1":
    md += ["", "(--quick: seed 1 only, no proposte.)"]
json.dump({"title": "Code-book economy (JPEG input, against the baseline commit)", "order": 15,
           "markdown": "\n".join(md), "figures": figures}, open(out, "w"), indent=1)
PY
