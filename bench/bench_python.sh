#!/usr/bin/env bash
# The Python module's batch throughput against the C++ batch path (bench/bench_python.py), run by
# bench/run.sh with --bin DIR (the module is DIR/../python, built with the programs).
exec /usr/bin/python3 "$(cd "$(dirname "$0")" && pwd)/bench_python.py" "$@"
