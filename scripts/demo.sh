#!/usr/bin/env bash
# Set up .venv if needed, then run the demo on the embedded scene; outputs go to demo_out/ (or the folder given).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/torch-modulo demo --out "${1:-demo_out}"
