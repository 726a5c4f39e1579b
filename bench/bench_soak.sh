#!/usr/bin/env bash
# The HTTP service under a long steady load (a soak: 50 clients for 10 minutes) and under random
# requests to every endpoint (a fuzz), against a real btfvq-server on loopback (bench/bench_soak.py).
# Usage (bench/run.sh): bench_soak.sh --bin DIR --json OUT --scratch DIR [--quick]
# BTFVQ_SOAK_ARGS adds flags of bench_soak.py (--soak-seconds, --clients, --fuzz-requests, --seed, ...).
# shellcheck disable=SC2086
exec /usr/bin/python3 "$(cd "$(dirname "$0")" && pwd)/bench_soak.py" "$@" ${BTFVQ_SOAK_ARGS:-}
