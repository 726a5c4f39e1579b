#!/usr/bin/env bash
# BTF-CIELab in `btfvq eval`: the time and peak memory of eval with and without
# `--metric btf-cielab` on a whole 256 x 256 sample (issue 19's acceptance: at most 3x the time of
# the plain eval, peak memory under 4 GB), as a user runs it:
#   btfvq synth --preset leather --size 256 --seed 1 --out leather256.zip
#   btfvq compress leather256.zip --db leather256.btfdb --name m
#   /usr/bin/time -v btfvq eval leather256.btfdb --material m --reference leather256.zip [--metric btf-cielab]
# BTFVQ_CIELAB_REPEATS (default 2) runs with the metric, each between two without; the fastest of each is kept.
# Usage (by bench/run.sh): bench_btf_cielab.sh --bin DIR --json OUT --scratch DIR [--quick (size 64)]
# BTFVQ_CIELAB_SAMPLE / BTFVQ_CIELAB_DB name an existing zip and database to use instead.
set -euo pipefail
bin="" json="" scratch="" size=256
while [ $# -gt 0 ]; do
  case "$1" in
    --bin) bin=$2; shift 2 ;;
    --json) json=$2; shift 2 ;;
    --scratch) scratch=$2; shift 2 ;;
    --testdata|--figures) shift 2 ;;
    --quick) size=64; shift ;;
    -h|--help) sed -n 2,11p "$0"; exit 0 ;;
    *) echo "bench_btf_cielab: unknown argument '$1'" >&2; exit 2 ;;
  esac
done
[ -n "$bin" ] && [ -n "$json" ] && [ -n "$scratch" ] || { echo "bench_btf_cielab: --bin, --json and --scratch are required" >&2; exit 2; }
mkdir -p "$scratch"
scratch=$(cd "$scratch" && pwd)
b="$bin/btfvq"
zip=${BTFVQ_CIELAB_SAMPLE:-$scratch/leather$size.zip}
db=${BTFVQ_CIELAB_DB:-$scratch/leather$size.btfdb}
[ -f "$zip" ] || "$b" synth --preset leather --size $size --seed 1 --out "$zip" > /dev/null
[ -f "$db" ] || "$b" compress "$zip" --db "$db" --name m > /dev/null
repeats=${BTFVQ_CIELAB_REPEATS:-2}
rows="$scratch/cielab_rows.jsonl"
: > "$rows"
# plain, cielab, plain, cielab, ..., plain: every run with the metric between two without, so that
# a change of the load on the shared machine shows in the plain runs.
schedule=(plain)
for r in $(seq 1 "$repeats"); do schedule+=(cielab plain); done
r=0
for mode in "${schedule[@]}"; do
    [ $mode = plain ] && r=$((r + 1))
    extra=(); [ $mode = cielab ] && extra=(--metric btf-cielab)
    out="$scratch/eval.$mode.$r"
    echo "bench_btf_cielab: eval $mode (run $r)" >&2
    load=$(cut -d' ' -f1 /proc/loadavg)
    /usr/bin/time -v -o "$out.time" "$b" eval "$db" --material m --reference "$zip" "${extra[@]}" --json "$out.json" > "$out.log"
    python3 - "$mode" "$r" "$out" "$load" >> "$rows" <<'PY'
import json, re, sys
mode, run, out, load = sys.argv[1:5]
t = open(out + ".time").read()
def field(name):
    return re.search(re.escape(name) + r": *(.*)", t).group(1).strip()
wall = field("Elapsed (wall clock) time (h:mm:ss or m:ss)")
parts = [float(p) for p in wall.split(":")]
seconds = sum(p * 60 ** i for i, p in enumerate(reversed(parts)))
e = json.load(open(out + ".json"))
print(json.dumps({"mode": mode, "run": int(run), "wall_s": seconds, "user_s": float(field("User time (seconds)")),
                  "system_s": float(field("System time (seconds)")), "peak_rss_mb": int(field("Maximum resident set size (kbytes)")) / 1024,
                  "load_before": float(load), "eval": e}))
PY
done
others=$(ps -eo pcpu,args --sort=-pcpu | awk 'NR > 1 && $1 > 5 {print $2}' | xargs -n1 basename 2>/dev/null | sort | uniq -c | awk '{print $2 " x" $1}' | paste -sd, - || true)
python3 - "$rows" "$json" "$size" "$others" "$(nproc)" <<'PY'
import json, sys
rows_file, out, size, others, cores = sys.argv[1:6]
rows = [json.loads(l) for l in open(rows_file)]
best = {m: min((r for r in rows if r["mode"] == m), key=lambda r: r["wall_s"]) for m in ("plain", "cielab")}
p, c = best["plain"], best["cielab"]
b = c["eval"]["btf_cielab"]
ratio = c["wall_s"] / p["wall_s"]
cpu = lambda r: r["user_s"] + r["system_s"]
cpu_ratio = cpu(c) / min(cpu(r) for r in rows if r["mode"] == "plain")
md = [f"`btfvq eval` of synthetic leather {size} x {size} (`btfvq synth --preset leather --size {size} --seed 1`, "
      "81 x 81 Bonn directions, compressed by `btfvq compress` at default settings), with and without "
      "`--metric btf-cielab` (default viewing condition: "
      f"{b['resolution']:.2f} texels per degree, {b['speed']:.0f} degrees per second), timed by `/usr/bin/time -v`; "
      f"fastest of {sum(r['mode'] == 'plain' for r in rows)} plain and {sum(r['mode'] == 'cielab' for r in rows)} BTF-CIELab runs (alternating), Release -O3 -march=native build, 2 threads.", "",
      "| eval | wall s | user + sys s | peak RSS MiB | BTF-CIELab mean / std / RMS | BTF-CIELab s | light blocks | working MiB |",
      "|---|---|---|---|---|---|---|---|",
      f"| plain | {p['wall_s']:.1f} | {p['user_s'] + p['system_s']:.1f} | {p['peak_rss_mb']:.0f} | | | | |",
      f"| `--metric btf-cielab` | {c['wall_s']:.1f} | {c['user_s'] + c['system_s']:.1f} | {c['peak_rss_mb']:.0f} | "
      f"{b['mean']:.4f} / {b['stddev']:.4f} / {b['rms']:.4f} | {b['seconds']:.1f} | {b['light_blocks']} | {b['working_bytes'] / 2**20:.0f} |",
      "",
      f"Time ratio {ratio:.2f}x in wall time, {cpu_ratio:.2f}x in CPU time (acceptance: at most 3x; on this shared "
      f"machine the CPU time is the steadier figure, the wall time follows the other sessions' load); peak memory {c['peak_rss_mb'] / 1024:.2f} GiB = {c['peak_rss_mb'] * 2**20 / 1e9:.2f} GB (acceptance: under 4 GB). "
      f"Plain CIEDE2000 mean of the same pair: {p['eval']['ciede2000_mean']:.4f}, MSSIM {p['eval']['mssim']:.4f}.", "",
      f"All runs (wall s, load average before each): " +
      ", ".join(f"{r['mode']} {r['wall_s']:.1f} ({r['load_before']:.1f})" for r in rows) +
      f". The machine has {cores} cores shared with other sessions; busy processes at the end: {others or 'none'}."]
json.dump({"title": "BTF-CIELab in eval (time and memory)", "order": 45, "markdown": "\n".join(md),
           "figures": {"plain": p, "btf_cielab": c, "time_ratio": ratio, "cpu_time_ratio": cpu_ratio,
                       "runs": [{k: r[k] for k in ("mode", "wall_s", "user_s", "system_s", "peak_rss_mb", "load_before")} for r in rows]}}, open(out, "w"), indent=1)
PY
