"""`avgs` on the device: the CLI as is; without matplotlib there, the curves PNG is skipped."""
import sys

import avgs.train.pipeline as pipeline
from avgs.cli import main

try:
    import matplotlib  # noqa: F401
except ImportError:
    pipeline.plot_curves = lambda *a, **k: None
sys.exit(main())
