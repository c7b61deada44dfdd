#!/usr/bin/env bash
# Set up .venv if needed, then run the demo on the embedded scene; outputs go to demo_out/ (or the folder given),
# relative to the folder the script is called from.
set -euo pipefail
out="${1:-demo_out}"
case "$out" in /*) ;; *) out="$PWD/$out" ;; esac
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/torch-modulo demo --out "$out"
