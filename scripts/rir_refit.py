"""Give an impulse-response checkpoint what ``avgs train`` now fits at its start without training again:
the early ILD's local correction (``RIRConfig.ild_local``) and the direct sound's level law
(``RIRConfig.direct_level``), fitted from the scene's training responses exactly as training does
(:meth:`avgs.train.impulse_responses.ImpulseResponseTraining.configure`); the weights and every other
buffer stay (neither fit depends on them). For checkpoints trained before these existed (the sweep
tables of docs/results.md, the bundled demo). ``--no-level``: the local correction alone.

    python scripts/rir_refit.py data/rir/two_rooms runs/two_rooms.ckpt runs/two_rooms.refit.ckpt
"""

from __future__ import annotations

import sys
import warnings

import torch

from avgs.io.checkpoint import config_of, load_checkpoint, save_checkpoint
from avgs.train.impulse_responses import ImpulseResponseTraining


class _Quiet:
    def write(self, record: dict) -> None:
        pass


def refit(scene_dir: str, ckpt_path: str, out_path: str, level: bool = True) -> str:
    """Write ``out_path``: ``ckpt_path`` with the local correction (and ``level``: the level law) fitted on
    ``scene_dir``; what was added, in words."""
    data = load_checkpoint(ckpt_path)
    cfg = config_of(data)
    if not (cfg.rir.direct_sound and cfg.rir.direct_ild):
        raise SystemExit(f"{ckpt_path}: no ILD law to correct (direct_sound and direct_ild must be on)")
    cfg.rir.ild_local = True
    cfg.rir.direct_level = level
    task = ImpulseResponseTraining(scene_dir, cfg)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        task.configure(cfg, _Quiet())
    if task.ild_table is None:
        raise SystemExit(f"{scene_dir}: too few training responses in sight of the source for the ILD law")
    at, residual, scale = task.ild_table
    data["config"]["rir"]["ild_local"] = True
    data["config"]["rir"]["ild_table"] = int(residual.shape[0])
    data["binauralizer"]["local_at"], data["binauralizer"]["local_residual"], data["binauralizer"]["local_scale"] = at, residual, scale
    said = f"{int(residual.shape[0])} training responses in the ILD's local correction"
    data["config"]["rir"]["direct_level"] = task.level_law is not None
    if task.level_law is not None:
        data["binauralizer"]["level_law"] = torch.tensor(task.level_law, dtype=torch.float32)
        said += ", the level law " + " / ".join(f"{c:.2f}" for c in task.level_law) + " dB"
    else:
        data["binauralizer"].pop("level_law", None)
    save_checkpoint(data, out_path)
    return said


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--no-level"]
    if len(args) != 3:
        print(__doc__)
        sys.exit(2)
    print(f"{args[2]}: {refit(*args, level='--no-level' not in sys.argv)}")
