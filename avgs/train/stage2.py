"""Stage 2: train G_a, F and B on the audio clips of one scene (paper §3.3).

:class:`Stage2Trainer` owns the optimizer, the learning-rate schedule, the batch sampler
and the point manager; the pipeline (:mod:`avgs.train.pipeline`) drives it and saves.
All training magnitudes are precomputed once (:class:`avgs.data.rwavs.ClipDataset`).
"""

from __future__ import annotations

import random

import numpy as np
import torch

from avgs.acoustics.model import AVGSModel
from avgs.acoustics.synthesis import binaural_waveform, mid_phase_waveform
from avgs.config import TrainConfig
from avgs.train.point_management import AudioPointManager
from avgs.train.losses import magnitude_loss, total_loss, volume_loss


def lr_factor(step: int, total: int, warmup_fraction: float, final_fraction: float) -> float:
    """Linear warm-up over ``warmup_fraction`` of ``total`` steps, then linear decay to ``final_fraction``."""
    warm = max(1, int(round(warmup_fraction * total)))
    if step < warm:
        return (step + 1) / warm
    rest = max(1, total - warm)
    t = min(1.0, (step - warm) / rest)
    return 1.0 - (1.0 - final_fraction) * t


class Stage2Trainer:
    """One optimisation step at a time; resumable through :meth:`state_dict`."""

    name = "stage 2"
    "How errors name this training."

    def __init__(self, model: AVGSModel, train_data, cfg: TrainConfig, device: str | torch.device = "cpu"):
        self._init_optimisation(model, train_data, cfg, device)
        self._to_device = {
            k: v.to(self.device) for k, v in (("listener", train_data.listener), ("theta", train_data.theta))
        }
        self._source = train_data.source.to(self.device)  # [3]
        self._mono_mag = train_data.mono_stft.abs().to(self.device)  # [C, F, N_t]
        self._binaural_mag = train_data.binaural_mag.to(self.device)  # [C, 2, F, N_t]

    def _init_optimisation(self, model, train_data, cfg: TrainConfig, device) -> None:
        """Model, data, Adam over F and B (and the tail's RT60, when B has one), X and alpha,
        the batch generator and the point manager: what every task's trainer shares."""
        self.model = model.to(device)
        self.data = train_data
        self.cfg = cfg
        self.device = torch.device(device)
        ac = cfg.acoustic
        self.total = int(ac.iterations)
        tail = getattr(model.binauralizer, "reverb", None)  # the impulse-response task's B has no tail
        rt60 = [] if tail is None else [tail.log_rt60]
        networks = [
            p for m in (model.field, model.binauralizer) if m is not None for p in m.parameters()
            if not any(p is q for q in rt60)
        ]
        groups = [
            {"params": networks, "lr": ac.lr, "name": "networks"},
            {"params": [model.points.X], "lr": ac.lr_points, "name": "X"},
            {"params": [model.points.alpha], "lr": ac.lr_alpha, "name": "alpha"},
        ]
        if rt60:
            # RT60 is one number per frequency for the whole scene, in log seconds: at the
            # networks' rate it could move only about a factor of 2 from its start in a
            # few thousand steps, and rooms range from 0.05 s to several seconds.
            groups.append({"params": rt60, "lr": ac.lr_rt60, "name": "rt60"})
        self.optimizer = torch.optim.Adam(groups)
        self.base_lrs = [g["lr"] for g in self.optimizer.param_groups]
        self.generator = torch.Generator().manual_seed(cfg.seed)  # batch sampling
        self.manager = AudioPointManager(
            cfg.points, self.total, generator=torch.Generator().manual_seed(cfg.seed + 1)
        )
        self.iteration = 0

    def _set_lr(self) -> None:
        ac = self.cfg.acoustic
        f = lr_factor(self.iteration, self.total, ac.warmup_fraction, ac.final_lr_fraction)
        for group, base in zip(self.optimizer.param_groups, self.base_lrs):
            group["lr"] = base * (f if group.get("name") in ("networks", "rt60") else 1.0)

    def _begin_step(self) -> torch.Tensor:
        """Training mode, this iteration's learning rates, and a random batch's indices [B]."""
        ac = self.cfg.acoustic
        self.model.train()
        self._set_lr()
        idx = torch.randint(len(self.data), (min(ac.batch_size, len(self.data)),), generator=self.generator)
        return idx.to(self.device)

    def step(self) -> dict:
        """One iteration on a random batch; returns the losses and point bookkeeping."""
        idx = self._begin_step()
        listener = self._to_device["listener"][idx]  # [B, 3]
        theta = self._to_device["theta"][idx]  # [B]
        (s_m, s_l, s_r), masks = self.model(listener, theta, self._source, self._mono_mag[idx])
        loss_m = magnitude_loss(s_m, s_l, s_r, self._binaural_mag[idx])
        return self._update(loss_m, masks.listener_vicinity, masks.source_vicinity)

    def _update(self, loss_m: torch.Tensor, listener_vicinity: torch.Tensor, source_vicinity: torch.Tensor) -> dict:
        """The step after the task's loss: the points' volume prior over both vicinities, the
        optimizer step and audio-aware point management; returns the losses and bookkeeping."""
        ac = self.cfg.acoustic
        vicinity = torch.cat([listener_vicinity.reshape(-1), source_vicinity.reshape(-1)])
        loss_v = volume_loss(self.model.points.alpha[torch.unique(vicinity)])
        loss = total_loss(loss_m, loss_v, ac.lambda_a)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if not torch.isfinite(loss):
            raise FloatingPointError(f"{self.name}: non-finite loss at iteration {self.iteration}")
        self.manager.step_post_backward(self.model.points, vicinity, self.model.vicinity_k)
        self.optimizer.step()
        self.iteration += 1
        added = self.manager.maybe_densify(self.iteration, self.model.points, self.optimizer)
        removed = self.manager.maybe_prune(self.iteration, self.model.points, self.optimizer)
        return {
            "loss": loss.item(),
            "loss_m": loss_m.item(),
            "loss_v": loss_v.item(),
            "points": self.model.points.num_points,
            "added": added,
            "removed": removed,
            "lr": self.optimizer.param_groups[0]["lr"],
        }

    @torch.no_grad()
    def predict(self, data, chunk: int = 16) -> torch.Tensor:
        """Binaural waveforms [C, 2, T] for every clip of ``data`` (a ClipDataset), synthesised as
        :meth:`avgs.render.renderer.SceneRenderer.render` does by default, so ``val_mag`` is ``avgs eval``'s MAG."""
        self.model.eval()
        source = data.source.to(self.device)
        cached = self.model.source_context(source)
        post_conv = self.model.binauralizer.post_conv
        length = data.mono.shape[-1]
        out = []
        for i in range(0, len(data), chunk):
            sl = slice(i, i + chunk)
            m = self.model.masks(data.listener[sl].to(self.device), data.theta[sl].to(self.device), source, cached)
            spec = data.mono_stft[sl].to(self.device)
            if post_conv is None:  # one phase retrieved for the mid, as render() does by default
                out.append(mid_phase_waveform(spec, m, length, self.cfg.stft)[0].cpu())
            else:  # the conv head: the source's phase, refined as render() refines it
                out.append(binaural_waveform(spec, m, length, self.cfg.stft, post_conv).cpu())
        return torch.cat(out)

    def evaluate(self, data) -> dict:
        """Validation MAG and ENV (docs/design.md, "Metrics and baselines"; :mod:`avgs.evaluation.metrics`), mean over clips."""
        from avgs.evaluation.metrics import env, mag

        pred = self.predict(data).numpy()  # [C, 2, T]
        gt = data.binaural.numpy()  # [C, 2, T]
        mags = [mag(p, g, self.cfg.stft) for p, g in zip(pred, gt)]
        envs = [env(p, g) for p, g in zip(pred, gt)]
        return {"val_mag": float(np.mean(mags)), "val_env": float(np.mean(envs))}

    # -- resume ------------------------------------------------------------------------

    def state_dict(self) -> dict:
        """Everything a resumed run needs to continue bit-identically (plain tensors and values,
        ``torch.load(weights_only=True)`` safe):

        ``iteration``; ``optimizer`` (Adam's moments and step counts, per parameter); ``schedule``
        (``total`` iterations, ``base_lrs`` and the last ``lr_factor``: the learning rate is a function of
        the iteration, recomputed each step); ``generator`` (the batch sampler's), ``manager_generator``
        (the point manager's: spawn positions and alpha) and ``manager`` (its densification statistics
        since the last densification, ``grad_sum`` and ``count``); ``torch_rng``, ``numpy_rng``,
        ``python_rng`` (the global generators) and, on CUDA, ``cuda_rng``.
        """
        np_state = np.random.get_state()
        py_version, py_words, py_gauss = random.getstate()
        ac = self.cfg.acoustic
        state = {
            "iteration": int(self.iteration),
            "optimizer": self.optimizer.state_dict(),
            "schedule": {
                "total": int(self.total),
                "base_lrs": [float(lr) for lr in self.base_lrs],
                "lr_factor": float(lr_factor(max(self.iteration - 1, 0), self.total, ac.warmup_fraction, ac.final_lr_fraction)),
            },
            "generator": self.generator.get_state(),
            "manager_generator": self.manager.generator.get_state(),
            "manager": self.manager.state_dict(),
            "torch_rng": torch.get_rng_state(),
            "numpy_rng": {
                "keys": torch.from_numpy(np.asarray(np_state[1], dtype=np.int64).copy()),
                "pos": int(np_state[2]),
                "has_gauss": int(np_state[3]),
                "cached_gaussian": float(np_state[4]),
            },
            "python_rng": {
                "version": int(py_version),
                "state": torch.tensor(py_words, dtype=torch.int64),
                "gauss_next": None if py_gauss is None else float(py_gauss),
            },
        }
        if self.device.type == "cuda" and torch.cuda.is_initialized():
            state["cuda_rng"] = [s.clone() for s in torch.cuda.get_rng_state_all()]
        return state

    def load_state_dict(self, state: dict) -> None:
        """Continue from :meth:`state_dict` (also from the shorter one of older checkpoints, which lacks the
        point manager's statistics and the global numpy / Python generators: such a run resumes, but
        densifies from fresh statistics). Raises ValueError when the state does not fit this model."""
        iteration = state["iteration"]
        if isinstance(iteration, bool) or not isinstance(iteration, int) or iteration < 0:
            raise ValueError(f"training state: iteration must be an integer >= 0, got {iteration!r}")
        self.optimizer.load_state_dict(self._fitting_optimizer_state(state["optimizer"]))
        try:
            self.generator.set_state(state["generator"])
            self.manager.generator.set_state(state["manager_generator"])
            torch.set_rng_state(state["torch_rng"])
        except (RuntimeError, TypeError) as exc:
            raise ValueError(f"training state: a random generator state is malformed ({exc})") from None
        self.manager.load_state_dict(state.get("manager"), self.model.points.num_points, self.model.points.X.device)
        if state.get("numpy_rng") is not None:
            s = state["numpy_rng"]
            np.random.set_state(("MT19937", s["keys"].numpy().astype(np.uint32), int(s["pos"]), int(s["has_gauss"]),
                                 float(s["cached_gaussian"])))
        if state.get("python_rng") is not None:
            s = state["python_rng"]
            try:
                random.setstate((int(s["version"]), tuple(int(w) for w in s["state"].tolist()), s["gauss_next"]))
            except (ValueError, TypeError) as exc:
                raise ValueError(f"training state: python_rng is malformed ({exc})") from None
        cuda = state.get("cuda_rng")
        if cuda is not None and self.device.type == "cuda" and len(cuda) == torch.cuda.device_count():
            torch.cuda.set_rng_state_all(cuda)
        self.iteration = int(iteration)

    def _fitting_optimizer_state(self, saved: dict) -> dict:
        """``saved`` (an Adam state dict) with this optimizer's hyperparameters, checked against the
        parameters it will be applied to: the same groups, the same number of parameters in each and
        per-parameter state tensors of the parameters' shapes. The moments and step counts come from the
        file; learning rates, betas and eps from the configuration (as in the run that saved it)."""
        current = self.optimizer.state_dict()
        groups = saved.get("param_groups") if isinstance(saved, dict) else None
        per_param = saved.get("state") if isinstance(saved, dict) else None
        if not isinstance(groups, list) or not isinstance(per_param, dict):
            raise ValueError("training state: 'optimizer' is not an optimizer state dict")
        if len(groups) != len(current["param_groups"]):
            raise ValueError(
                f"training state: the optimizer has {len(groups)} parameter groups, this model needs "
                f"{len(current['param_groups'])}"
            )
        params = [p for g in self.optimizer.param_groups for p in g["params"]]
        merged_groups, shapes = [], {}
        for i, (mine, theirs) in enumerate(zip(current["param_groups"], groups)):
            ids = theirs.get("params") if isinstance(theirs, dict) else None
            if not isinstance(ids, list) or len(ids) != len(mine["params"]):
                raise ValueError(
                    f"training state: optimizer group {i} ({mine.get('name', i)}) holds "
                    f"{len(ids) if isinstance(ids, list) else '?'} parameters, this model has {len(mine['params'])}"
                )
            merged_groups.append({**mine, "params": list(ids)})
            for pid, own in zip(ids, mine["params"]):
                shapes[pid] = (mine.get("name", i), tuple(params[own].shape))
        for pid, entry in per_param.items():
            if pid not in shapes or not isinstance(entry, dict):
                raise ValueError(f"training state: optimizer state for an unknown parameter {pid!r}")
            name, shape = shapes[pid]
            for key, value in entry.items():
                if key == "step":
                    continue
                if isinstance(value, torch.Tensor) and tuple(value.shape) != shape:
                    raise ValueError(
                        f"training state: optimizer {key} of group {name} has shape {tuple(value.shape)}, "
                        f"the parameter has {shape}"
                    )
        return {"state": per_param, "param_groups": merged_groups}
