#!/usr/bin/env bash
# Sets up ilcc_graph on a fresh Debian machine: the system library Open3D needs, a virtual
# environment in .venv, and the package with its test extras and Open3D (an optional extra of the
# package: the tests and benchmarks that compare our readers and board search against it use it).
# Safe to run again: it only does what is missing. Usage: bash scripts/setup.sh
set -euo pipefail
cd "$(dirname "$0")/.."

say() { printf '[setup] %s\n' "$*"; }

# 1. libusb-1.0-0: Open3D's wheel links against it.
have_libusb() {  # grep without -q: reading all of ldconfig's output avoids SIGPIPE under pipefail
  ldconfig -p 2>/dev/null | grep 'libusb-1.0.so.0' >/dev/null
}
if ! have_libusb; then
  if [ "$(id -u)" = 0 ]; then
    say "installing the system library libusb-1.0-0 (Open3D needs it): apt-get install -y libusb-1.0-0"
    apt-get update -qq >/dev/null
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
  elif command -v sudo >/dev/null 2>&1; then
    say "installing the system library libusb-1.0-0 (Open3D needs it) with sudo"
    sudo apt-get update -qq >/dev/null
    sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
  else
    say "Open3D needs the system library libusb-1.0-0; install it (apt-get install -y libusb-1.0-0) and run again" >&2
    exit 1
  fi
else
  say "libusb-1.0-0 present"
fi

# 2. The virtual environment and the package (re-installed only when pyproject.toml changed).
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  say "creating the virtual environment .venv"
  "$PY" -m venv .venv
fi
stamp=.venv/.ilcc_graph-installed
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  say "installing ilcc_graph and its dependencies into .venv (gtsam, opencv, open3d, ...; a few minutes the first time)"
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -e '.[test,open3d]'
  echo "$want" > "$stamp"
else
  say "ilcc_graph already installed in .venv"
fi
say "ready: .venv/bin/ilcc-graph --help"
