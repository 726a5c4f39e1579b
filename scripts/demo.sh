#!/usr/bin/env bash
# The demo: a synthetic material through the pipeline, end to end.
set -euo pipefail
bin=${1:-build/bin}
out=demo-output
rm -rf "$out"; mkdir -p "$out"
"$bin/btfvq" synth --preset leather --size 64 --seed 1 --out "$out/leather.zip"
"$bin/btfvq" info "$out/leather.zip"
echo "demo: synthetic sample written to $out/leather.zip"
