#!/usr/bin/env bash
# The README's first command: set everything up (idempotent), then open the desktop
# explorer on the bundled demo scene. Extra arguments go to avgs-viewer
# (e.g. `bash scripts/run.sh path/to/scene.ckpt`).
#
# With no display (a server, a container) the window cannot open: the demo is rendered
# off screen instead, to demo_view.png and demo_binaural.wav in the current folder.
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
bash "$here/scripts/setup.sh"
if [ -z "${DISPLAY:-}" ] && [ -z "${WAYLAND_DISPLAY:-}" ]; then
  echo "run: no display (DISPLAY is unset): rendering the demo scene off screen instead of opening the window"
  exec "$here/.venv/bin/avgs-viewer" "$@" --screenshot demo_view.png --audio demo_binaural.wav
fi
exec "$here/.venv/bin/avgs-viewer" "$@"
