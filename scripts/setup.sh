#!/usr/bin/env bash
# Sets up ilcc_graph on a fresh Debian machine: a virtual environment in .venv and the package
# with its test extras. Safe to run again: it only does what is missing. Usage: bash scripts/setup.sh
# Open3D is optional (only benchmarks compare against it): .venv/bin/pip install -e '.[open3d]'
# after apt-get install -y libusb-1.0-0 (its wheel links against that system library).
set -euo pipefail
cd "$(dirname "$0")/.."

say() { printf '[setup] %s\n' "$*"; }

# The virtual environment and the package (re-installed only when pyproject.toml changed).
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  say "creating the virtual environment .venv"
  "$PY" -m venv .venv
fi
stamp=.venv/.ilcc_graph-installed
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  say "installing ilcc_graph and its dependencies into .venv (gtsam, opencv, ...; a few minutes the first time)"
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -e '.[test]'
  echo "$want" > "$stamp"
else
  say "ilcc_graph already installed in .venv"
fi
say "ready: .venv/bin/ilcc-graph --help"
