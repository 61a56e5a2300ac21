#!/usr/bin/env bash
# The tests of cmsckf-fleet (fleet/tests), as CI and `cargo test` run them:
#   fleet/run-tests.sh [VENV] [PYTEST ARGS...]
# Makes a virtual environment at VENV (default: target/tmp/fleet-venv; never the
# system's Python, which Debian refuses, PEP 668), installs ./fleet[test] into it
# from PyPI (Ray, pyarrow, mcap, pytest, PyYAML), and runs pytest on embedded Ray
# with the binary CMSCKF_BIN (default: target/release/cmsckf).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
venv="${1:-$root/target/tmp/fleet-venv}"
shift || true
mkdir -p "$(dirname "$venv")"
venv="$(cd "$(dirname "$venv")" && pwd)/$(basename "$venv")"  # absolute: pytest runs from fleet/

export CMSCKF_BIN="${CMSCKF_BIN:-$root/target/release/cmsckf}"
if [ ! -x "$CMSCKF_BIN" ]; then
  echo "run-tests.sh: no cmsckf binary at $CMSCKF_BIN (build it, or set CMSCKF_BIN)" >&2
  exit 1
fi
CMSCKF_BIN="$(cd "$(dirname "$CMSCKF_BIN")" && pwd)/$(basename "$CMSCKF_BIN")"  # absolute, as venv

if [ ! -x "$venv/bin/python" ]; then
  python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check "$root/fleet[test]"

# No bytecode or pytest cache in the source tree; embedded Ray, never a cluster
# that happens to be named in the environment. Ray's sessions (each with its
# nodes' copies of the binary, ~100 MB apiece, which Ray never removes), the
# tasks' scratch files and pytest's go to one temporary directory, removed at
# the end. Its name is short: Ray's Unix sockets live under it (108 bytes at most).
export PYTHONDONTWRITEBYTECODE=1
unset RAY_ADDRESS
scratch="$(mktemp -d /tmp/cfleet.XXXXXX)"
trap 'rm -rf "$scratch"' EXIT
export RAY_TMPDIR="$scratch" TMPDIR="$scratch"
cd "$root/fleet"
status=0
"$venv/bin/python" -m pytest -p no:cacheprovider -q tests "$@" || status=$?
exit "$status"
