"""3D-GS adaptive density control (clone, split, prune, opacity reset) as a strategy object.

Modelled on gsplat's ``DefaultStrategy``: the caller owns the strategy's ``state`` dict and
calls two hooks around ``loss.backward()``::

    strategy = DensifyStrategy.from_config(cfg, scene_scale)
    state = strategy.initialize_state()
    ...
    strategy.step_pre_backward(aux)                      # keep the 2D means' gradient
    loss.backward()
    strategy.step_post_backward(model, optimizer, state, step, aux, generator)
    optimizer.step()

Every change of the point set replaces the model's parameters and, in the same move,
the optimizer's per-point state (Adam's moments: kept rows follow their points, new rows
start at zero), so the optimizer always matches the model.

Rules (3D-GS / gsplat defaults): the screen-space gradient of each Gaussian's 2D mean,
in NDC units, is averaged over the views that saw it; above ``grow_grad2d`` a Gaussian is
cloned when small (max scale <= ``grow_scale3d`` x scene scale) and split in two when large
(new centres drawn from the Gaussian itself, scales / 1.6). Gaussians with opacity below
``prune_opacity`` are removed, and after the first opacity reset also those larger than
``prune_scale3d`` x scene scale. Every ``reset_every`` steps all opacities are clamped to
``2 x prune_opacity``. Growth never takes the count above ``max_gaussians`` (the highest
gradients win), and pruning always leaves at least one Gaussian.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from avgs.gaussians.model import GaussianModel
from avgs.gaussians.projection import quat_to_rotmat


def update_params_and_optimizer(model: GaussianModel, optimizer: torch.optim.Optimizer, param_fn, state_fn, names=None) -> None:
    """Replace parameters ``names`` (default all) of ``model`` by ``param_fn(name, old)`` and
    each per-point optimizer state tensor by ``state_fn(name, key, old)``.

    Optimizer groups are found by the identity of the parameter they hold (one per group).
    """
    groups = {id(p): g for g in optimizer.param_groups for p in g["params"]}
    for name in names or list(model.params.keys()):
        old = model.params[name]
        n = old.shape[0]
        new = nn.Parameter(param_fn(name, old.detach()), requires_grad=old.requires_grad)
        group = groups.get(id(old))
        if group is not None:
            st = optimizer.state.pop(old, {})
            for key, v in list(st.items()):
                if isinstance(v, torch.Tensor) and v.dim() > 0 and v.shape[0] == n:
                    st[key] = state_fn(name, key, v)
            group["params"] = [new if p is old else p for p in group["params"]]
            if st:
                optimizer.state[new] = st
        model.params[name] = new


def _cat_zeros(v: torch.Tensor, n: int) -> torch.Tensor:
    return torch.cat([v, v.new_zeros((n, *v.shape[1:]))])


def duplicate(model: GaussianModel, optimizer, mask: torch.Tensor) -> int:
    """Clone the Gaussians in ``mask [N]`` (the copy is appended; its optimizer state starts at zero)."""
    sel = torch.nonzero(mask).squeeze(-1)
    if len(sel):
        update_params_and_optimizer(
            model, optimizer, lambda _, p: torch.cat([p, p[sel]]), lambda _, __, v: _cat_zeros(v, len(sel))
        )
    return int(len(sel))


def split(model: GaussianModel, optimizer, mask: torch.Tensor, generator: torch.Generator | None = None) -> int:
    """Replace each Gaussian in ``mask [N]`` by two drawn from it, with scales / 1.6."""
    sel = torch.nonzero(mask).squeeze(-1)
    n = len(sel)
    if n == 0:
        return 0
    rest = torch.nonzero(~mask).squeeze(-1)
    p = model.params
    scales = torch.exp(p["log_scales"].detach()[sel])  # [n, 3]
    rot = quat_to_rotmat(p["quats"].detach()[sel])  # [n, 3, 3]
    gen_device = generator.device if generator is not None else scales.device
    noise = torch.randn(2, n, 3, generator=generator, dtype=scales.dtype, device=gen_device).to(scales.device)
    samples = torch.einsum("nij,nj,bnj->bni", rot, scales, noise)  # [2, n, 3] offsets in the Gaussian's frame

    def param_fn(name, old):
        if name == "means":
            new = (old[sel][None] + samples).reshape(-1, 3)
        elif name == "log_scales":
            new = torch.log(scales / 1.6).repeat(2, 1)
        else:
            new = old[sel].repeat(2, *[1] * (old.dim() - 1))
        return torch.cat([old[rest], new])

    update_params_and_optimizer(model, optimizer, param_fn, lambda _, __, v: _cat_zeros(v[rest], 2 * n))
    return n


def remove(model: GaussianModel, optimizer, mask: torch.Tensor) -> int:
    """Drop the Gaussians in ``mask [N]`` and their optimizer state."""
    keep = ~mask
    n = int(mask.sum())
    if n:
        update_params_and_optimizer(model, optimizer, lambda _, p: p[keep], lambda _, __, v: v[keep])
    return n


def reset_opacity(model: GaussianModel, optimizer, value: float) -> None:
    """Clamp every opacity to at most ``value`` and zero the opacity's optimizer state."""
    cap = math.log(value / (1.0 - value))
    update_params_and_optimizer(
        model,
        optimizer,
        lambda _, p: p.clamp_max(cap),
        lambda _, __, v: torch.zeros_like(v),
        names=["opacity_logits"],
    )


@dataclass
class DensifyStrategy:
    """Clone / split / prune / reset on a schedule (see the module docstring)."""

    scene_scale: float = 1.0
    "Scene extent the 3D scale thresholds are relative to."
    refine_start: int = 500
    refine_stop: int = 15_000
    refine_every: int = 100
    reset_every: int = 3000
    grow_grad2d: float = 2e-4
    grow_scale3d: float = 0.01
    prune_opacity: float = 0.005
    prune_scale3d: float = 0.1
    max_gaussians: int = 200_000

    @classmethod
    def from_config(cls, cfg, scene_scale: float) -> "DensifyStrategy":
        """From a :class:`avgs.config.GaussianConfig`."""
        return cls(
            scene_scale=float(scene_scale),
            refine_start=cfg.densify_from,
            refine_stop=cfg.densify_until,
            refine_every=cfg.densify_every,
            reset_every=cfg.reset_opacity_every,
            grow_grad2d=cfg.densify_grad_threshold,
            grow_scale3d=cfg.grow_scale3d,
            prune_opacity=cfg.prune_opacity,
            prune_scale3d=cfg.prune_scale3d,
            max_gaussians=cfg.max_gaussians,
        )

    def initialize_state(self) -> dict:
        """The caller-owned running statistics (filled lazily to the model's size)."""
        return {"grad2d": None, "count": None}

    def step_pre_backward(self, aux: dict) -> None:
        """Ask autograd to keep the gradient of the projected means."""
        m2d = aux["means2d"]
        if m2d.requires_grad:
            m2d.retain_grad()

    def step_post_backward(self, model: GaussianModel, optimizer, state: dict, step: int, aux: dict, generator=None) -> dict:
        """Accumulate statistics and, on schedule, refine; returns what changed (empty if nothing)."""
        if step >= self.refine_stop:
            return {}
        self._update_state(model, state, aux)
        out: dict = {}
        if step > self.refine_start and step % self.refine_every == 0:
            out["cloned"], out["split"] = self._grow(model, optimizer, state, generator)
            out["pruned"] = self._prune(model, optimizer, step)
            state["grad2d"] = state["count"] = None
        if self.reset_every > 0 and step % self.reset_every == 0 and step > 0:
            reset_opacity(model, optimizer, 2 * self.prune_opacity)
            out["reset_opacity"] = True
        return out

    # -- internals ----------------------------------------------------------------------

    def _update_state(self, model: GaussianModel, state: dict, aux: dict) -> None:
        grad = aux["means2d"].grad
        n = len(model)
        if state["grad2d"] is None or len(state["grad2d"]) != n:
            state["grad2d"] = torch.zeros(n, device=model.means.device)
            state["count"] = torch.zeros(n, device=model.means.device)
        if grad is None:
            return
        g = grad.detach().reshape(-1, 2).clone()  # [N, 2] pixels -> NDC units
        g[:, 0] *= aux["width"] / 2.0 * aux["n_cameras"]
        g[:, 1] *= aux["height"] / 2.0 * aux["n_cameras"]
        seen = torch.nonzero(aux["radii"].reshape(-1) > 0).squeeze(-1)
        state["grad2d"].index_add_(0, seen, g[seen].norm(dim=-1))
        state["count"].index_add_(0, seen, torch.ones_like(seen, dtype=state["count"].dtype))

    def _grow(self, model: GaussianModel, optimizer, state: dict, generator) -> tuple[int, int]:
        grads = state["grad2d"] / state["count"].clamp_min(1)  # [N]
        high = grads > self.grow_grad2d
        budget = max(0, self.max_gaussians - len(model))
        if int(high.sum()) > budget:  # each grown Gaussian adds one net: keep the largest gradients
            top = torch.topk(torch.where(high, grads, torch.full_like(grads, -1.0)), budget).indices
            high = torch.zeros_like(high)
            high[top] = True
        small = torch.exp(model.params["log_scales"].detach()).max(-1).values <= self.grow_scale3d * self.scene_scale
        n_dupli = duplicate(model, optimizer, high & small)
        is_split = torch.cat([high & ~small, torch.zeros(n_dupli, dtype=torch.bool, device=high.device)])
        n_split = split(model, optimizer, is_split, generator)
        return n_dupli, n_split

    def _prune(self, model: GaussianModel, optimizer, step: int) -> int:
        p = model.params
        prune = torch.sigmoid(p["opacity_logits"].detach()) < self.prune_opacity
        if step > self.reset_every:
            prune |= torch.exp(p["log_scales"].detach()).max(-1).values > self.prune_scale3d * self.scene_scale
        if bool(prune.all()):  # never empty the scene: keep the most opaque
            prune[torch.argmax(p["opacity_logits"].detach())] = False
        return remove(model, optimizer, prune)
