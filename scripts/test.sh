#!/usr/bin/env bash
# The tests on a fresh machine: the interop tests' Python peers (OpenCV, Cyclone DDS,
# mcap, websockets, protobuf) in a project-local virtual environment, Debian's Fast DDS
# for the C++ peer, then every test of the workspace.
#
#   scripts/test.sh [cargo test arguments]
#
# The interpreter the tests run is $OUTLET_PYTHON; unset, it is .venv/bin/python,
# created here from tests/requirements.txt when missing or out of date. Nothing is
# installed outside the project, with one exception: a Debian/Ubuntu python3
# without its venv module (package python3-venv) gets that package from apt-get
# when this runs as root; otherwise the script stops and says what to install.
set -euo pipefail
cd "$(dirname "$0")/.."
root="$PWD"
requirements="$root/tests/requirements.txt"

setup_venv() {
  local venv="$root/.venv" stamp want
  want="$(sha256sum "$requirements" | cut -d' ' -f1)"
  stamp="$venv/.outlet-requirements.sha256"
  if [ -x "$venv/bin/python" ] && [ "$(cat "$stamp" 2>/dev/null)" = "$want" ]; then
    return
  fi
  local python="${PYTHON:-python3}"
  if ! command -v "$python" >/dev/null 2>&1; then
    echo "scripts/test.sh: $python not found: the interop tests need Python 3 (3.9 or newer)" >&2
    exit 2
  fi
  if ! "$python" -c 'import venv, ensurepip' >/dev/null 2>&1; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
      echo "== installing python3-venv (apt-get): $python has no venv module" >&2
      apt-get update -qq && apt-get install -y -qq python3-venv >/dev/null
    else
      echo "scripts/test.sh: $python has no venv module; install it (Debian/Ubuntu: apt-get install python3-venv)" >&2
      exit 2
    fi
  fi
  echo "== Python test peers: $venv (from tests/requirements.txt)" >&2
  rm -rf "$venv"
  "$python" -m venv "$venv"
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-input -r "$requirements"
  echo "$want" >"$stamp"
}

# The Fast DDS interop test builds a C++ peer against Debian's Fast DDS (the test fails,
# naming the packages, without them). As for python3-venv: installed with apt-get when
# this runs as root, otherwise the script says what to install.
setup_fastdds() {
  if command -v c++ >/dev/null 2>&1 && [ -f /usr/include/fastdds/dds/domain/DomainParticipantFactory.hpp ] \
    && [ -f /usr/include/fastcdr/Cdr.h ]; then
    return
  fi
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "== installing g++, libfastrtps-dev, libfastcdr-dev (apt-get): the Fast DDS interop test's peer" >&2
    apt-get update -qq && apt-get install -y -qq g++ libfastrtps-dev libfastcdr-dev >/dev/null
  else
    echo "scripts/test.sh: the Fast DDS interop test needs g++, libfastrtps-dev and libfastcdr-dev" \
      "(Debian/Ubuntu: sudo apt-get install g++ libfastrtps-dev libfastcdr-dev)" >&2
    exit 2
  fi
}
setup_fastdds

if [ -z "${OUTLET_PYTHON:-}" ]; then
  setup_venv
  export OUTLET_PYTHON="$root/.venv/bin/python"
fi
echo "== Python test peers: $OUTLET_PYTHON" >&2

# --no-fail-fast: a failing test binary must not hide the ones after it.
exec cargo test --workspace --locked --no-fail-fast "$@"
