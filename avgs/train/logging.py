"""Training logs: a JSON-lines file (one record per line, appended as training goes) and
a PNG of the loss and point-count curves (matplotlib, Agg back end, written atomically)."""

from __future__ import annotations

import json
import math
from pathlib import Path

from avgs.io.atomic import atomic_path, write_text


def log_paths(checkpoint: str | Path) -> tuple[Path, Path]:
    """(``<ckpt>.log.jsonl``, ``<ckpt>.curves.png``) next to the checkpoint."""
    ckpt = Path(checkpoint)
    return ckpt.with_name(ckpt.name + ".log.jsonl"), ckpt.with_name(ckpt.name + ".curves.png")


def _plain(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


class Unlogged:
    """A log that keeps nothing: fits made again for what they compute (a resumed run's training pairs,
    ``scripts/rir_refit.py``), whose records the run's log already holds."""

    def write(self, record: dict) -> None:
        pass


class JsonLinesLog:
    """Append-only JSON-lines log that also keeps its records in memory."""

    def __init__(self, path: str | Path, records: list[dict] | None = None):
        """Start ``path`` afresh with ``records`` (e.g. the history of a resumed checkpoint)."""
        self.path = Path(path)
        self.records: list[dict] = [dict(r) for r in (records or [])]
        write_text(self.path, "".join(json.dumps(r) + "\n" for r in self.records))

    def write(self, record: dict) -> None:
        record = {k: _plain(v) for k, v in record.items()}
        self.records.append(record)
        try:
            with open(self.path, "a", encoding="utf-8") as f:
                f.write(json.dumps(record) + "\n")
        except OSError as exc:  # a full disk: the file's name in the one line the CLI prints
            raise OSError(exc.errno, f"cannot write {self.path}: {exc.strerror or exc}") from None


def plot_curves(records: list[dict], path: str | Path) -> Path:
    """Loss (log scale), validation MAG and audio point count against the iteration."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    path = Path(path)
    fig = Figure(figsize=(10, 3.2), dpi=100)
    axes = fig.subplots(1, 3)

    def series(stage: str, key: str):
        pts = [(r["iteration"], r[key]) for r in records if r.get("stage") == stage and r.get(key) is not None]
        return [p[0] for p in pts], [p[1] for p in pts]

    for stage, label in (("stage1", "stage 1 (RGB)"), ("stage2", "stage 2 (audio)")):
        x, y = series(stage, "loss")
        if x:
            # Losses of single small batches are noisy: draw them faintly, and a running mean over
            # about a tenth of the run on top.
            line = axes[0].plot(x, y, alpha=0.25, linewidth=0.8)[0]
            w = max(1, len(y) // 10)
            smooth = [sum(y[max(0, i - w + 1): i + 1]) / (i + 1 - max(0, i - w + 1)) for i in range(len(y))]
            axes[0].plot(x, smooth, color=line.get_color(), label=label)
    axes[0].set_yscale("log")
    axes[0].set_title("loss")
    axes[0].legend(fontsize=7)
    x, y = series("stage2", "val_mag")
    if x:
        axes[1].plot(x, y, "o-")
        axes[1].set_title("validation MAG")
    else:  # the impulse-response task: log-magnitude error, against predicting the mean response
        x, y = series("stage2", "val_logmag")
        axes[1].plot(x, y, "o-", label="model")
        xm, ym = series("stage2", "val_logmag_mean")
        if xm:
            axes[1].plot(xm, ym, "--", label="mean response")
            axes[1].legend(fontsize=7)
        axes[1].set_title("validation log-magnitude error")
    x, y = series("stage2", "points")
    axes[2].plot(x, y)
    axes[2].set_title("audio points")
    for ax in axes:
        ax.set_xlabel("iteration")
    # Fixed margins: tight_layout measured every tick label, 0.4 s of a run's last second.
    fig.subplots_adjust(left=0.075, right=0.99, bottom=0.15, top=0.91, wspace=0.3)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return path
