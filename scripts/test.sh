#!/usr/bin/env bash
# The README's second command: set everything up (idempotent), then run the whole test
# suite headless (pytest-xvfb starts its own Xvfb for the GUI tests; no display or sound
# card needed). Extra arguments go to pytest; the slow training runs are left out unless
# you pass `-m slow` or `-m ""`. Two worker processes (pytest-xdist; AVGS_TEST_WORKERS=N, or
# `-n 0` for one process), one torch thread each: on 2 cores the default suite takes 4.5-5.5 min
# by the host's speed (the same run cost 8.6-10.8 min of CPU on one machine within an hour).
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
bash "$here/scripts/setup.sh"
cd "$here"
if [ "$#" -eq 0 ]; then set -- -m "not slow"; fi
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"
# Byte-code caches on: every CLI, viewer and Ray subprocess the tests start would otherwise compile
# the package again.
unset PYTHONDONTWRITEBYTECODE
exec .venv/bin/python -m pytest -q -n "${AVGS_TEST_WORKERS:-2}" "$@"
