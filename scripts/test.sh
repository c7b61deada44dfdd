#!/usr/bin/env bash
# Set up .venv if needed, then run the test suite (doctests included). Tests marked slow are skipped unless
# --runslow is given; extra arguments go to pytest, e.g. `bash scripts/test.sh --runslow -x`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/python -m pytest -q "$@"
