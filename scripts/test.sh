#!/usr/bin/env bash
# The README's second command: set everything up (idempotent), then run the whole test
# suite headless (pytest-xvfb starts its own Xvfb for the GUI tests; no display or sound
# card needed). Extra arguments go to pytest; the slow training runs are left out unless
# you pass `-m slow` or `-m ""`. Two worker processes (pytest-xdist; AVGS_TEST_WORKERS=N, or
# `-n 0` for one process), one torch thread each: on 2 cores the default suite takes 4:25 on the
# slower of our hosts (7.6 min of CPU; 2026-11-29; a clean clone's first run compiles for longer).
# The scenes and models several test files share are built once for both workers
# (tests/built_once.py); a third worker gains nothing on 2 cores.
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
