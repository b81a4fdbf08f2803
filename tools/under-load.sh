#!/usr/bin/env bash
# Runs a command with N busy-loop processes beside it (a robot's computer is never idle):
#   tools/under-load.sh [-n N] COMMAND...     (default N = 2; `make test-under-load`)
# The loops are killed when the command ends, whatever its exit status, which it returns.
set -euo pipefail
n=2
if [ "${1:-}" = "-n" ]; then n="$2"; shift 2; fi
[ $# -gt 0 ] || { echo "usage: $0 [-n N] COMMAND..." >&2; exit 2; }
pids=()
trap 'kill "${pids[@]}" 2>/dev/null || true' EXIT
for _ in $(seq "$n"); do
  python3 -c 'while True: pass' &
  pids+=($!)
done
"$@"
