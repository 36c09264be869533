#!/usr/bin/env bash
# The README's second command: set everything up (idempotent), then run the whole test
# suite headless (pytest-xvfb starts its own Xvfb for the GUI tests; no display or sound
# card needed). Extra arguments go to pytest; the slow training runs are left out unless
# you pass `-m slow` or `-m ""`.
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
bash "$here/scripts/setup.sh"
cd "$here"
if [ "$#" -eq 0 ]; then set -- -m "not slow"; fi
exec .venv/bin/python -m pytest -q "$@"
