"""Peak RSS of rendering a long clip, whole (``SceneRenderer.render`` then ``write_audio``, what
``avgs render`` does) or in blocks (:func:`avgs.render.chunked.render_to_file`); benchmarks/memory.md.

    OMP_NUM_THREADS=1 .venv/bin/python scripts/render_memory.py CKPT METHOD IN.wav OUT.wav whole|blocks

RSS is sampled every 2 ms by a thread (psutil) and printed after each stage: imports, load, read, render.
"""

import sys
import threading
import time

import psutil
import torch

torch.set_num_threads(1)
proc, top = psutil.Process(), [0]


def sample() -> None:
    while True:
        top[0] = max(top[0], proc.memory_info().rss)
        time.sleep(0.002)


threading.Thread(target=sample, daemon=True).start()


def report(stage: str) -> None:
    print(f"{stage:10s} rss {proc.memory_info().rss / 2**20:6.0f} MB  peak {top[0] / 2**20:6.0f} MB", flush=True)


from avgs.config import SynthesisConfig  # noqa: E402
from avgs.io.atomic import write_audio  # noqa: E402
from avgs.io.audio_input import read_mono  # noqa: E402
from avgs.render.chunked import render_to_file  # noqa: E402
from avgs.render.renderer import SceneRenderer  # noqa: E402

ckpt, method, inp, out, how = sys.argv[1:6]
report("imports")
r = SceneRenderer.load(ckpt, synthesis=SynthesisConfig(method=method))
report("load")
x = read_mono(inp, r.sample_rate)
report("read")
t0 = time.perf_counter()
if how == "whole":
    write_audio(out, r.render((1, 1, 1.6), 30.0, x).binaural, r.sample_rate)
else:
    render_to_file(r, out, (1, 1, 1.6), 30.0, x)
report(f"render ({time.perf_counter() - t0:.1f} s)")
