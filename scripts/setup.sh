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
# pip's output as a few progress lines (its full output in .venv/pip.log, shown on failure):
# every 10th package collected, then the install; on a terminal one line redrawn in place.
pip_quietly() {
  local what=$1 hint=$2; shift 2
  local log=.venv/pip.log tty=0 cols=80
  [ -t 1 ] && tty=1 && cols=$(tput cols 2>/dev/null || echo 80)
  if ! .venv/bin/python -u -m pip install --progress-bar off "$@" 2>&1 | tee -a "$log" | awk -v what="$what" -v hint="$hint" -v tty="$tty" -v cols="$cols" '
    function show(s, final) {  # on a terminal: one line redrawn, cut to its width (a wrapped one stays)
      if (tty) { printf "\r\033[K[setup]   %s", (final ? s "\n" : substr(s, 1, cols - 11)) }
      else if (final) { printf "[setup]   %s\n", s }
      fflush()
    }
    /^Collecting |^Processing |^Requirement already satisfied: / {
      n++; name = ($1 == "Requirement") ? $4 : $2; sub(/.*\//, "", name); sub(/(-[0-9]|[<>=!~;[(]).*/, "", name)
      show(what ": " n " package(s) looked at (" name ")", !tty && n % 10 == 0)
    }
    /^ *Downloading / { name = $2; sub(/.*\//, "", name); sub(/-[0-9].*/, "", name); show(what ": downloading " name " " $(NF-1) " " $NF, 0) }
    /^Installing collected packages/ { show(what ": " n " package(s) looked at", 1); show(what ": installing" hint, 1) }
    /^Successfully installed/ { show(what ": installed " NF - 2 " package(s)", 1) }
    END { if (tty) printf "\r\033[K" }'; then
    say "pip failed; the end of its output (all of it in $log):" >&2
    tail -n 30 "$log" >&2
    exit 1
  fi
}
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  say "installing ilcc_graph and its dependencies into .venv (gtsam, opencv, open3d, ...; a few minutes the first time)"
  : > .venv/pip.log
  pip_quietly "pip" "" --upgrade pip
  pip_quietly "ilcc_graph" " (a minute or two; the big ones are gtsam, opencv, open3d)" -e '.[test,open3d]'
  echo "$want" > "$stamp"
else
  say "ilcc_graph already installed in .venv"
fi
# 3. The package's bytecode, written ahead: an editable install compiles nothing, and where
# PYTHONDONTWRITEBYTECODE is set every process would compile the package's sources again on import
# (0.3 s a process: the command, each worker, each of the tests' subprocesses). Files already
# compiled are skipped; a source edited later is compiled again on import as usual.
.venv/bin/python -m compileall -q ilcc_graph factors >/dev/null || say "could not write the bytecode ahead (imports compile it instead)"
say "ready: .venv/bin/ilcc-graph --help"
