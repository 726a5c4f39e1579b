#!/usr/bin/env bash
# Whole-sample compression as a user runs it (issue 17, part 5): tile, leather and wool from
# `btfvq synth --size 256 --seed 1` and the real proposte (the original database in
# tests/data/btfbase/proposte, imported and decoded at the 81 x 81 measured directions), each written
# as a UBO2003 JPEG zip, then compressed end to end, load included, at default settings:
#   /usr/bin/time -v btfvq compress SAMPLE.zip --db X.btfdb --name m --report X.json
# The table splits the wall time into load / resample (on its own thread, overlapping the phases) /
# phase 1 / 2 / refinement / phase 3 / write, with CPU seconds beside the phases, and gives total
# wall and CPU seconds, CPU/wall of the growing phases, peak memory, ratio and the paper's 23.4 hours
# of one core per 256 x 256 sample divided by the wall time.
# Usage (by bench/run.sh): bench_speed.sh --bin DIR --json OUT --scratch DIR --testdata DIR [--quick]
# (--quick: the synthetic presets at 64 x 64 and no proposte). BTFVQ_SPEED_SAMPLES=tile,leather,wool,proposte
# picks the samples.
set -euo pipefail
bin="" json="" scratch="" testdata="" size=256
samples=${BTFVQ_SPEED_SAMPLES:-tile,leather,wool,proposte}
while [ $# -gt 0 ]; do
  case "$1" in
    --bin) bin=$2; shift 2 ;;
    --json) json=$2; shift 2 ;;
    --scratch) scratch=$2; shift 2 ;;
    --testdata) testdata=$2; shift 2 ;;
    --figures) shift 2 ;;
    --quick) size=64; samples=${samples//,proposte/}; shift ;;
    -h|--help) sed -n 2,14p "$0"; exit 0 ;;
    *) echo "bench_speed: unknown argument '$1'" >&2; exit 2 ;;
  esac
done
[ -n "$bin" ] && [ -n "$json" ] && [ -n "$scratch" ] && [ -n "$testdata" ] ||
  { echo "bench_speed: --bin, --json, --scratch and --testdata are required" >&2; exit 2; }
mkdir -p "$scratch"
scratch=$(cd "$scratch" && pwd)
b="$bin/btfvq"
rows="$scratch/speed_rows.jsonl"
: > "$rows"
for s in ${samples//,/ }; do
  zip="$scratch/$s.zip"
  if [ "$s" = proposte ]; then
    "$b" import-btfbase "$testdata/btfbase/proposte" --db "$scratch/proposte-original.btfdb" > /dev/null
    "$b" decode "$scratch/proposte-original.btfdb" --material proposte --out "$zip" > /dev/null
  else
    "$b" synth --preset "$s" --size "$size" --seed 1 --out "$zip" > /dev/null
  fi
  echo "bench_speed: compress $s" >&2
  load=$(cut -d' ' -f1 /proc/loadavg)
  rm -f "$scratch/$s.btfdb"
  /usr/bin/time -v -o "$scratch/$s.time" "$b" compress "$zip" --db "$scratch/$s.btfdb" --name m \
    --report "$scratch/$s.json" > "$scratch/$s.log"
  python3 - "$s" "$scratch/$s" "$load" >> "$rows" <<'PY'
import json, re, sys
name, base, load = sys.argv[1:4]
t = open(base + ".time").read()
def field(label):
    return re.search(re.escape(label) + r": *(.*)", t).group(1).strip()
wall = sum(float(p) * 60 ** i for i, p in enumerate(reversed(field("Elapsed (wall clock) time (h:mm:ss or m:ss)").split(":"))))
r = json.load(open(base + ".json"))
m = r["materials"][0]
ph = m["phases"]
print(json.dumps({"sample": name, "width": m["width"], "height": m["height"], "wall_s": wall,
                  "cpu_s": float(field("User time (seconds)")) + float(field("System time (seconds)")),
                  "peak_rss_mb": int(field("Maximum resident set size (kbytes)")) / 1024, "load_before": float(load),
                  "load_s": m["seconds"]["load"], "resample_s": m["seconds"]["resample"] + m["seconds"]["resample_operator"],
                  "phase_s": [p["seconds"] for p in ph], "phase_cpu_s": [p["cpu_seconds"] for p in ph],
                  "refine_s": m["refine"].get("seconds", 0.0), "write_s": r["write_seconds"],
                  "bytes": r["bytes"], "ratio": r["compression_ratio"], "search": m["search"]["path"]}))
PY
done
others=$(ps -eo pcpu,args --sort=-pcpu | awk 'NR > 1 && $1 > 5 {print $2}' | xargs -n1 basename 2>/dev/null | sort | uniq -c | awk '{print $2 " x" $1}' | paste -sd, - || true)
python3 - "$rows" "$json" "$others" "$(nproc)" <<'PY'
import json, sys
rows_file, out, others, cores = sys.argv[1:5]
rows = [json.loads(l) for l in open(rows_file)]
paper_s = 23.4 * 3600
md = ["Each sample written as a UBO2003 JPEG zip (81 x 81 Bonn directions) and compressed end to end by "
      "`/usr/bin/time -v btfvq compress SAMPLE.zip --db X.btfdb --name m --report X.json` at default settings "
      "(configs/pipeline.json), Release -O3 -march=native build. Synthetic samples: `btfvq synth --preset P --seed 1`; "
      "proposte: the original database of tests/data/btfbase/proposte imported and decoded (`btfvq decode`, JPEG quality 95). "
      "Seconds are wall seconds of each stage, CPU seconds of the process over the stage in brackets; resampling runs "
      "on its own thread beside the phases (its sum is not part of the total). Paper: 23.4 hours of one core per "
      "256 x 256 sample (paper 000, Sec. 6).", "",
      "| sample | load s | resample s | phase 1 s | phase 2 s | refine s | phase 3 s | write s | wall s | CPU s | growing CPU/wall | peak RSS MB | ratio | vs 23.4 h |",
      "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
for r in rows:
    p, c = r["phase_s"], r["phase_cpu_s"]
    grow = (c[0] + c[1]) / max(p[0] + p[1], 1e-9)
    r["growing_cpu_per_wall"] = grow
    md.append(f"| {r['sample']} {r['width']} | {r['load_s']:.1f} | {r['resample_s']:.1f} | {p[0]:.1f} ({c[0]:.1f}) | "
              f"{p[1]:.1f} ({c[1]:.1f}) | {r['refine_s']:.1f} | {p[2]:.1f} ({c[2]:.1f}) | {r['write_s']:.1f} | "
              f"**{r['wall_s']:.1f}** | {r['cpu_s']:.1f} | {grow:.2f} | {r['peak_rss_mb']:.0f} | 1:{r['ratio']:.0f} | "
              f"{paper_s / r['wall_s']:.0f}x |")
md += ["", "Issue 17's acceptance: at most 180 s wall and 4 GB peak memory per 256 x 256 sample, growing-phase "
       "CPU/wall at least 1.7 on leather and wool. Here: " +
       "; ".join(f"{r['sample']} {r['wall_s']:.0f} s ({'within' if r['wall_s'] <= 180 else 'over'} 180), "
                 f"{r['peak_rss_mb'] * 2**20 / 1e9:.2f} GB, growing CPU/wall {r['growing_cpu_per_wall']:.2f}" for r in rows) + ".",
       "", "Load average before each run: " + ", ".join(f"{r['sample']} {r['load_before']:.1f}" for r in rows) +
       f". The machine has {cores} cores shared with other sessions; busy processes at the end: {others or 'none'}."]
json.dump({"title": "Whole-sample compression time and memory", "order": 31, "markdown": "\n".join(md),
           "figures": {"rows": rows}}, open(out, "w"), indent=1)
PY
