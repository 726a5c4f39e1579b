#!/usr/bin/env bash
# The demo: a synthetic material compressed end to end through the REST API.
#   server (embedded defaults: SQLite + a local data directory) -> synth -> submit (upload) -> watch
#   -> download (sha256 verified) -> eval (ratio, MSSIM) -> render a preview -> stop the server.
set -euo pipefail
bin=$(cd "${1:-build/bin}" && pwd)
out=demo-output
data=var/demo-data
rm -rf "$out" "$data"
mkdir -p "$out" "$data"

port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
export BTFVQ_SERVER="http://127.0.0.1:$port"
"$bin/btfvq-server" --listen "127.0.0.1:$port" --data "$data" >"$out/server.log" 2>&1 &
server=$!
trap 'kill "$server" 2>/dev/null || true; wait "$server" 2>/dev/null || true' EXIT
for _ in $(seq 1 100); do
  curl -fsS "$BTFVQ_SERVER/healthz" >/dev/null 2>&1 && break
  sleep 0.1
done
curl -fsS "$BTFVQ_SERVER/healthz" >/dev/null || { echo "demo: the server did not start; see $out/server.log"; exit 1; }
echo "demo: btfvq-server listening on $BTFVQ_SERVER (data in $data)"

"$bin/btfvq" synth --preset leather --size 64 --seed 1 --out "$out/leather.zip"
"$bin/btfvq" info "$out/leather.zip"
job=$("$bin/btfvq" submit --db demo --upload "$out/leather.zip")
echo "demo: submitted job $job"
"$bin/btfvq" watch "$job"
"$bin/btfvq" download demo --out "$out/demo.btfdb"
"$bin/btfvq" ls
"$bin/btfvq" eval "$out/demo.btfdb" --material leather --reference "$out/leather.zip" --json "$out/eval.json"
# The 64 x 64 material repeats 4 times around the sphere, so that a texel is a few pixels, not a block.
"$bin/btfvq" render "$out/demo.btfdb" --material leather --scene sphere --size 512 --light 45,135 --tiles 4 \
  --out "$out/preview.png"
echo
echo "demo: database: $out/demo.btfdb"
echo "demo: preview:  $out/preview.png (the material on a 512 x 512 sphere, lit from the upper left)"
echo "demo: metrics:  $out/eval.json"
