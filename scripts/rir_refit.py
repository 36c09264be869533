"""Give an impulse-response checkpoint what ``avgs train`` now fits at its start without training again:
the early ILD's law, the direct sound's level law (``RIRConfig.direct_level``) and the walls' early
reflections (``RIRConfig.early_reflections``: the walls found in the checkpoint's own points, the ILD
law refitted with their gain), fitted from the scene's
training responses exactly as training does (:meth:`avgs.train.impulse_responses.ImpulseResponseTraining.configure`
and ``fit_reflections``); the weights and every other buffer stay (no fit depends on them). For
checkpoints trained before these existed (the tables of docs/results.md, the bundled demo).
``--no-level``: without the level law; ``--no-reflections``: without the walls' reflections; ``--no-arrival``:
without the first reflection's arrival behind a wall (``RIRConfig.reflected_arrival``); ``--no-lag``: without the
first sound's lag behind a wall (``RIRConfig.blocked_lag``); ``--no-blocked-ild``: without the early ILD's
factor behind a wall (``RIRConfig.blocked_ild``, fitted with the checkpoint's own B); ``--local``: with
the local correction (off by default since the walls' reflections: ``RIRConfig.ild_local``). ``--blocked-ild-only``:
the checkpoint as it is but for that factor (what it adds, measured alone). ``--geometry-only``: the straight path's
test, the walls' reflections, the lag and that factor fitted again on the checkpoint's own points, as training now
does at its end (:meth:`~avgs.train.impulse_responses.ImpulseResponseTraining.refit_geometry`), nothing else changed.

    python scripts/rir_refit.py data/rir/two_rooms runs/two_rooms.ckpt runs/two_rooms.refit.ckpt
"""

from __future__ import annotations

import sys
import warnings

import torch

from avgs.acoustics.rir_binauralizer import REFLECTION_BUFFERS, RIRBinauralizer
from avgs.io.checkpoint import config_of, load_checkpoint, save_checkpoint
from avgs.render.renderer import SceneRenderer
from avgs.train.impulse_responses import ImpulseResponseTraining
from avgs.train.logging import Unlogged



def refit(scene_dir: str, ckpt_path: str, out_path: str, level: bool = True, reflections: bool = True,
          local: bool = False, arrival: bool = True, lag: bool = True, blocked_ild: bool = True,
          only_blocked_ild: bool = False, only_geometry: bool = False) -> str:
    """Write ``out_path``: ``ckpt_path`` with the level law (``level``), the walls' reflections
    (``reflections``; with ``arrival`` also behind a wall) and the early ILD's local correction (``local``)
    fitted on ``scene_dir``, and behind a wall the first sound's lag (``lag``, ``RIRConfig.blocked_lag``), each left
    out when not asked for; what was added, in words."""
    data = load_checkpoint(ckpt_path)
    cfg = config_of(data)
    if only_blocked_ild:
        return _fit_blocked_ild(scene_dir, data, ckpt_path, out_path)
    if only_geometry:
        return _refit_geometry(scene_dir, data, ckpt_path, out_path)
    cfg.rir.ild_local = local
    cfg.rir.direct_level = level
    task = _configured(scene_dir, cfg, ckpt_path)
    if task.ild_law is None:
        raise SystemExit(f"{scene_dir}: too few training responses in sight of the source for the ILD law")
    data["binauralizer"]["ild_law"] = torch.tensor(task.ild_law, dtype=torch.float32)
    data["config"]["rir"]["ild_local"] = task.ild_table is not None
    data["config"]["rir"]["ild_table"] = 0 if task.ild_table is None else int(task.ild_table[1].shape[0])
    for key in ("local_at", "local_residual", "local_scale"):
        data["binauralizer"].pop(key, None)
    said = ""
    if task.ild_table is not None:
        at, residual, scale = task.ild_table
        data["binauralizer"]["local_at"], data["binauralizer"]["local_residual"], data["binauralizer"]["local_scale"] = at, residual, scale
        said += f", {int(residual.shape[0])} training responses in the ILD's local correction"
    data["config"]["rir"]["direct_level"] = task.level_law is not None
    if task.level_law is not None:
        data["binauralizer"]["level_law"] = torch.tensor(task.level_law, dtype=torch.float32)
        said += ", the level law " + " / ".join(f"{c:.2f}" for c in task.level_law) + " dB"
    else:
        data["binauralizer"].pop("level_law", None)
    data["config"]["rir"]["early_reflections"] = reflections
    data["config"]["rir"]["reflected_arrival"] = reflections and arrival
    for key in REFLECTION_BUFFERS:
        data["binauralizer"].pop(key, None)
    if reflections:  # the walls from the checkpoint's points, as training finds them once G_a is built
        empty = RIRBinauralizer(config_of(data).rir, None, 1, 1, 1.0).state_dict()
        data["binauralizer"].update({k: empty[k] for k in REFLECTION_BUFFERS if k in empty})
        renderer = SceneRenderer(data, path=ckpt_path)
        task.fit_reflections(renderer.model)
        state = renderer.model.binauralizer.state_dict()
        for key in ("ild_law", "local_residual") + REFLECTION_BUFFERS:
            if key in state:
                data["binauralizer"][key] = state[key].detach().float().cpu().clone()
        walls = int((state["reflecting_walls"][:, :2].abs().sum(-1) > 0).sum())
        said += f", {walls} walls' reflections (gain {float(state['reflection_gain']):.2f})"
        if "reflected_arrival" in state:
            direction, delay = (float(v) > 0.5 for v in state["reflected_arrival"])
            said += (f"; behind a wall the {'first reflection' if direction else 'straight line'}'s direction and "
                     f"the {'first reflection' if delay else 'straight line'}'s delay")
    data["config"]["rir"]["blocked_lag"] = lag
    data["binauralizer"].pop("blocked_lag", None)
    if lag:  # behind a wall, the first sound's lag after the straight line (after the first reflection's fit)
        data["binauralizer"]["blocked_lag"] = torch.tensor(0.0)
        renderer = SceneRenderer(data, path=ckpt_path)
        task.fit_lag(renderer.model)
        data["binauralizer"]["blocked_lag"] = renderer.model.binauralizer.blocked_lag.detach().float().cpu().clone()
        said += f"; behind a wall the first sound {1e3 * float(data['binauralizer']['blocked_lag']):.1f} ms after the straight line"
    data["config"]["rir"]["blocked_ild"] = blocked_ild
    data["binauralizer"].pop("blocked_ild", None)
    if blocked_ild:  # behind a wall, B's early ILD scaled (after every fit above: the responses it scores are the final ones)
        said += "; " + _with_blocked_ild(task, data, ckpt_path)
    law = " / ".join(f"{float(c):.2f}" for c in data["binauralizer"]["ild_law"])
    save_checkpoint(data, out_path)
    return f"the ILD law {law} dB" + said


def _configured(scene_dir: str, cfg, ckpt_path: str) -> ImpulseResponseTraining:
    """The training task of ``scene_dir`` configured with ``cfg`` (a checkpoint's, with a direct sound's ILD) as
    training's start does: the fits from the training responses, kept in the task (nothing written)."""
    if not (cfg.rir.direct_sound and cfg.rir.direct_ild):
        raise SystemExit(f"{ckpt_path}: no ILD law to refit (direct_sound and direct_ild must be on)")
    task = ImpulseResponseTraining(scene_dir, cfg)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        task.configure(cfg, Unlogged())
    return task


def _with_blocked_ild(task: ImpulseResponseTraining, data: dict, ckpt_path: str) -> str:
    """``data`` (a checkpoint whose config says ``blocked_ild``) given the factor that ``task`` fits with its B."""
    data["binauralizer"]["blocked_ild"] = torch.tensor(1.0)
    renderer = SceneRenderer(data, path=ckpt_path)
    task.fit_blocked_ild(renderer.model)
    data["binauralizer"]["blocked_ild"] = renderer.model.binauralizer.blocked_ild.detach().float().cpu().clone()
    return f"behind a wall B's early ILD times {float(data['binauralizer']['blocked_ild']):.1f}"


def _fit_blocked_ild(scene_dir: str, data: dict, ckpt_path: str, out_path: str) -> str:
    """``--blocked-ild-only``: the checkpoint with the early ILD's factor behind a wall and nothing else refitted."""
    task = _configured(scene_dir, config_of(data), ckpt_path)  # the training responses' early ILDs
    data["config"]["rir"]["blocked_ild"] = True
    said = _with_blocked_ild(task, data, ckpt_path)
    save_checkpoint(data, out_path)
    return said


def _refit_geometry(scene_dir: str, data: dict, ckpt_path: str, out_path: str) -> str:
    """``--geometry-only``: the checkpoint with its straight path's tests fitted again on its own points (and the
    early ILD's factor behind a wall after them, where its config has one), as training's end now fits them."""
    task = _configured(scene_dir, config_of(data), ckpt_path)
    renderer = SceneRenderer(data, path=ckpt_path)
    model, b = renderer.model, renderer.model.binauralizer
    task._log = None
    task.refit_geometry(model)
    if getattr(b, "blocked_ild", None) is not None:
        task.fit_blocked_ild(model)
    state, weights = b.state_dict(), {name for name, _ in b.named_parameters()}
    for key in data["binauralizer"]:
        if key in state and key not in weights:
            data["binauralizer"][key] = state[key].detach().cpu().clone()
    save_checkpoint(data, out_path)
    lag = "" if b.blocked_lag is None else f", lag {1e3 * float(b.blocked_lag):.1f} ms"
    shrink = "" if getattr(b, "blocked_ild", None) is None else f", B's early ILD behind a wall times {float(b.blocked_ild):.1f}"
    return f"behind a wall from {float(b.sight_blocked):g} points on the path{lag}{shrink}"


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a not in ("--no-level", "--no-reflections", "--no-arrival", "--no-lag", "--no-blocked-ild",
                                                 "--blocked-ild-only", "--geometry-only", "--local")]
    if len(args) != 3:
        print(__doc__)
        sys.exit(2)
    said = refit(*args, level="--no-level" not in sys.argv, reflections="--no-reflections" not in sys.argv,
                 local="--local" in sys.argv, arrival="--no-arrival" not in sys.argv, lag="--no-lag" not in sys.argv,
                 blocked_ild="--no-blocked-ild" not in sys.argv, only_blocked_ild="--blocked-ild-only" in sys.argv,
                 only_geometry="--geometry-only" in sys.argv)
    print(f"{args[2]}: {said}")
