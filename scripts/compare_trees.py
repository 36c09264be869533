"""Run an ``avgs`` command from another source tree and print its time in this process (s).

    git archive REV avgs avgs_viewer | tar -x -C /tmp/before
    python scripts/compare_trees.py /tmp/before render assets/demo/scene.ckpt --listener 1 1 1 ...
    python scripts/compare_trees.py .           render assets/demo/scene.ckpt --listener 1 1 1 ...

The tree goes first on ``sys.path`` and the script checks that its ``avgs`` is the one
imported: ``PYTHONPATH=/tmp/before python -c ...`` run from the checkout would import the
checkout's, since the current folder comes before ``PYTHONPATH`` there.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path


def main() -> int:
    if len(sys.argv) < 3:
        print(__doc__, file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    tree = str(Path(sys.argv[1]).resolve())
    sys.path.insert(0, tree)
    import avgs

    if not str(Path(avgs.__file__).resolve()).startswith(tree):
        print(f"imported avgs from {avgs.__file__}, not from {tree}", file=sys.stderr)
        return 2
    from avgs.cli import main as avgs_main

    status = avgs_main(sys.argv[2:])
    print(f"{time.perf_counter() - t0:.2f}")
    return status


if __name__ == "__main__":
    sys.exit(main())
