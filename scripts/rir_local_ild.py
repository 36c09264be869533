"""Give an impulse-response checkpoint the early ILD's local correction (``RIRConfig.ild_local``) without
training again: the table is fitted from the scene's training responses exactly as ``avgs train`` does
at its start (:meth:`avgs.train.impulse_responses.ImpulseResponseTraining.configure`); the weights and
every other buffer stay. For checkpoints trained before the correction existed (the sweep tables of
docs/results.md, the bundled demo).

    python scripts/rir_local_ild.py data/rir/two_rooms runs/two_rooms.ckpt runs/two_rooms.local.ckpt
"""

from __future__ import annotations

import sys
import warnings

from avgs.io.checkpoint import config_of, load_checkpoint, save_checkpoint
from avgs.train.impulse_responses import ImpulseResponseTraining


class _Quiet:
    def write(self, record: dict) -> None:
        pass


def add_local_ild(scene_dir: str, ckpt_path: str, out_path: str) -> int:
    """Write ``out_path``: ``ckpt_path`` with the local correction fitted on ``scene_dir``; its entries."""
    data = load_checkpoint(ckpt_path)
    cfg = config_of(data)
    if not (cfg.rir.direct_sound and cfg.rir.direct_ild):
        raise SystemExit(f"{ckpt_path}: no ILD law to correct (direct_sound and direct_ild must be on)")
    cfg.rir.ild_local = True
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
    save_checkpoint(data, out_path)
    return int(residual.shape[0])


if __name__ == "__main__":
    if len(sys.argv) != 4:
        print(__doc__)
        sys.exit(2)
    print(f"{sys.argv[3]}: {add_local_ild(*sys.argv[1:])} training responses in the correction")
