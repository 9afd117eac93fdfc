#!/usr/bin/env bash
# Second README command: install (same step as setup) and run the whole test suite,
# notebooks included (executed in short mode).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
export AWIWI_SHORT=1 MPLBACKEND=Agg
# two worker processes (pytest-xdist, dev extra): the suite on both cores of the 2-core CI machine
python3 -m pytest -q -n 2 "$@"
