#!/usr/bin/env bash
# First README command: set everything up, then run the main demo.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
awiwi-drake demo --out out/demo
