#!/usr/bin/env bash
# Second README command: install (same step as setup) and run the whole test suite,
# notebooks included (executed in short mode).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
export AWIWI_SHORT=1 MPLBACKEND=Agg
python3 -m pytest -q "$@"
