#!/usr/bin/env bash
# Install awiwi_drake (editable, with the dev extra) and, if possible, Graphviz `dot`.
# Graphviz is optional: without it diagrams are written as .dot only (the code says so).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
"$PY" -m pip install --disable-pip-version-check -q -e ".[dev]"
if ! command -v dot >/dev/null 2>&1; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "install.sh: installing Graphviz (Debian package 'graphviz') for SVG/PNG diagram export"
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq graphviz >/dev/null) \
      || echo "install.sh: could not install Graphviz; diagrams will be exported as .dot only"
  else
    echo "install.sh: Graphviz 'dot' not found and cannot be installed here; diagrams will be exported as .dot only"
  fi
fi
