#!/usr/bin/env python3
"""Assembles the JSON written by each bench_* program into BENCHMARKS.md and latest.json.

Each program writes {"title": str, "order": int, "markdown": str, "figures": {...}}; the markdown is
its section, the figures are machine-readable numbers that land in latest.json.
"""
import argparse, datetime, json, os, platform, subprocess

def sh(cmd):
    try:
        return subprocess.check_output(cmd, shell=True, text=True, stderr=subprocess.DEVNULL).strip()
    except subprocess.CalledProcessError:
        return ""

def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--results", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--json", required=True)
    ap.add_argument("--command", required=True)
    ap.add_argument("--commit", required=True, help="the commit as bench/run.sh names it (with \" (dirty)\")")
    a = ap.parse_args()
    sections = []
    for f in sorted(os.listdir(a.results)):
        if f.endswith(".json"):
            with open(os.path.join(a.results, f)) as fh:
                sections.append(json.load(fh))
    sections.sort(key=lambda s: (s.get("order", 100), s.get("title", "")))
    machine = {
        "cpu": sh("lscpu | sed -n 's/^Model name: *//p'"),
        "cores": os.cpu_count(),
        "memory_gb": round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1),
        "os": sh(". /etc/os-release && echo $PRETTY_NAME"),
        "compiler": sh("c++ --version | head -1"),
        "opencl": sh("clinfo -l 2>/dev/null | tr '\\n' ' '"),
    }
    commit = a.commit
    when = datetime.datetime.utcnow().strftime("%Y-%m-%d %H:%M UTC")
    lines = ["# btfvq benchmarks", "",
             f"Assembled by `{a.command}` (bench/run.sh) on {when}, commit {commit}; each section says "
             "which run measured it (bench/results/sections/).", "",
             f"Machine: {machine['cpu']}, {machine['cores']} cores, {machine['memory_gb']} GB, {machine['os']}; "
             f"{machine['compiler']}; OpenCL: {machine['opencl'] or 'none'}.", "",
             "Absolute times on a shared 2-core machine are noisy; ratios measured within one run are the figures to trust.", ""]
    for s in sections:
        lines += [f"## {s['title']}", ""]
        p = s.get("provenance")
        if p and not s.get("own_provenance"):
            lines += [f"*Measured by `{p['command']}` at commit {p['commit']} on {p['date']}.*", ""]
        lines += [s["markdown"].rstrip(), ""]
    with open(a.out, "w") as fh:
        fh.write("\n".join(lines))
    with open(a.json, "w") as fh:
        json.dump({"machine": machine, "commit": commit, "date": when, "command": a.command,
                   "benchmarks": {s["title"]: dict(s.get("figures", {}), provenance=s.get("provenance"))
                                  for s in sections}}, fh, indent=2)

if __name__ == "__main__":
    main()
