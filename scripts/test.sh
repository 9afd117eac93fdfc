#!/usr/bin/env bash
# Second README command: install (same step as setup) and run the whole test suite,
# notebooks included (executed in short mode).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
export AWIWI_SHORT=1 MPLBACKEND=Agg
# one BLAS thread per worker: two xdist workers already fill both cores, and OpenBLAS's idle threads spin on the
# suite's many small linear-algebra calls (measured: eigvals of the hand's 194 x 194 Jacobian 0.3-3.9 s under
# oversubscription against 13-35 ms with one thread)
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
# two worker processes (pytest-xdist, dev extra): the suite on both cores of the 2-core CI machine
python3 -m pytest -q -n 2 "$@"
