"""Audio-aware point management (paper §3.3) as a small strategy object, like gsplat's.

The caller owns the training loop and calls, per iteration::

    manager.step_post_backward(points, vicinity_indices)   # after loss.backward()
    optimizer.step()
    added = manager.maybe_densify(step, points, optimizer)
    removed = manager.maybe_prune(step, points, optimizer)

Densification: every ``densify_every`` iterations, each point that was in a vicinity
since the last densification gets its gradient magnitude ``k ||dL/dX||`` (k the vicinity
size, see :meth:`AudioPointManager.step_post_backward`) averaged over the iterations it
was seen; those above tau_g spawn one new point drawn from a Gaussian around their
position, with random alpha (drawn from N(0, std of alpha per dimension)). At most
``densify_max_fraction`` of the points spawn per step (the strongest), so G_a grows
where the error is, not everywhere at once.
Pruning: every ``prune_every`` iterations, Open3D radius outlier removal (fewer than
``prune_min_neighbors`` neighbours within ``prune_radius``, normalised units).
Adding or removing points also grows or slices the optimizer's per-parameter state.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from avgs.acoustics.points import AudioPoints
from avgs.config import PointManagementConfig


def _replace_rows(optimizer: torch.optim.Optimizer | None, old: nn.Parameter, new: nn.Parameter, keep: torch.Tensor | None, n_new: int) -> None:
    """Point ``optimizer`` at ``new`` in place of ``old``, carrying its state.

    Rows ``keep`` (bool [N_old] or None for all) of every per-row state tensor are kept, then
    ``n_new`` zero rows appended (fresh Adam moments for spawned points).
    """
    if optimizer is None:
        return
    for group in optimizer.param_groups:
        for i, p in enumerate(group["params"]):
            if p is not old:
                continue
            group["params"][i] = new
            state = optimizer.state.pop(old, None)
            if state is None:
                continue
            for key, value in state.items():
                if isinstance(value, torch.Tensor) and value.dim() > 0 and value.shape[0] == old.shape[0]:
                    if keep is not None:
                        value = value[keep]
                    if n_new:
                        value = torch.cat([value, value.new_zeros((n_new, *value.shape[1:]))])
                    state[key] = value
            optimizer.state[new] = state


def update_points(
    points: AudioPoints,
    optimizer: torch.optim.Optimizer | None,
    keep: torch.Tensor | None = None,
    new_X: torch.Tensor | None = None,
    new_alpha: torch.Tensor | None = None,
) -> None:
    """Keep rows ``keep`` (bool [N]) of G_a, append ``new_X [M,3]``/``new_alpha [M,D]``, and update ``optimizer``."""
    X, alpha = points.X.detach(), points.alpha.detach()
    if keep is not None:
        X, alpha = X[keep], alpha[keep]
    n_new = 0
    if new_X is not None:
        n_new = len(new_X)
        X = torch.cat([X, new_X.to(X)])
        alpha = torch.cat([alpha, new_alpha.to(alpha)])
    X_param, alpha_param = nn.Parameter(X.contiguous()), nn.Parameter(alpha.contiguous())
    _replace_rows(optimizer, points.X, X_param, keep, n_new)
    _replace_rows(optimizer, points.alpha, alpha_param, keep, n_new)
    points.set_points(X_param, alpha_param)


class AudioPointManager:
    """Accumulates vicinity gradients; densifies and prunes G_a on schedule."""

    def __init__(self, cfg: PointManagementConfig, total_iterations: int, generator: torch.Generator | None = None):
        if cfg.enabled and (int(cfg.densify_every) < 1 or int(cfg.prune_every) < 1):
            raise ValueError(
                f"point management needs densify_every and prune_every >= 1, got {cfg.densify_every} and {cfg.prune_every}"
            )
        self.cfg = cfg
        self.densify_until = int(cfg.densify_until_fraction * total_iterations)
        self.generator = generator or torch.Generator().manual_seed(0)
        self.grad_sum: torch.Tensor | None = None  # [N]
        self.count: torch.Tensor | None = None  # [N]

    def _reset(self, n: int, device) -> None:
        self.grad_sum = torch.zeros(n, device=device)
        self.count = torch.zeros(n, device=device)

    # -- resume ------------------------------------------------------------------------

    def state_dict(self) -> dict:
        """The densification statistics gathered since the last densification (plain tensors or None):
        ``grad_sum [N]``, ``count [N]``. With :meth:`load_state_dict` and the generator's state
        (which the caller saves, :meth:`avgs.train.stage2.Stage2Trainer.state_dict`), a resumed run
        densifies exactly as an uninterrupted one."""
        def plain(t):
            return None if t is None else t.detach().cpu().clone()

        return {"grad_sum": plain(self.grad_sum), "count": plain(self.count)}

    def load_state_dict(self, state: dict | None, n_points: int, device=None) -> None:
        """Restore :meth:`state_dict` for a G_a of ``n_points`` points (ValueError if it does not fit)."""
        state = state or {}
        grad_sum, count = state.get("grad_sum"), state.get("count")
        if grad_sum is None and count is None:
            self.grad_sum = self.count = None
            return
        for name, t in (("grad_sum", grad_sum), ("count", count)):
            if not isinstance(t, torch.Tensor) or tuple(t.shape) != (n_points,):
                raise ValueError(f"point manager: {name} must be a tensor [{n_points}], got {t!r:.60}")
        self.grad_sum = grad_sum.detach().to(device=device).clone()
        self.count = count.detach().to(device=device).clone()

    def step_post_backward(self, points: AudioPoints, vicinity: torch.Tensor, vicinity_size: int = 1) -> None:
        """Accumulate ``vicinity_size * ||dL/dX||`` of the points in ``vicinity`` (any-shaped int64 indices).

        F averages its features over the k points of a vicinity, so each point's raw
        gradient shrinks as 1/k: with the paper's k = 15 % of N it depends on how many
        points the scene has. Scaled by k it is the gradient of the point's own feature
        before averaging, which tau_g can be compared with whatever N and k are.
        """
        if not self.cfg.enabled or points.X.grad is None:
            return
        n = points.num_points
        if self.grad_sum is None or len(self.grad_sum) != n:
            self._reset(n, points.X.device)
        idx = torch.unique(vicinity.reshape(-1))
        self.grad_sum[idx] += float(vicinity_size) * points.X.grad[idx].norm(dim=-1)
        self.count[idx] += 1

    def maybe_densify(self, step: int, points: AudioPoints, optimizer: torch.optim.Optimizer | None) -> int:
        """At densification steps, spawn points around significant ones; returns how many were added."""
        cfg = self.cfg
        if not cfg.enabled or step <= 0 or step % cfg.densify_every or step > self.densify_until:
            return 0
        if self.grad_sum is None or len(self.grad_sum) != points.num_points:
            return 0
        mean_grad = self.grad_sum / self.count.clamp_min(1)  # [N]
        significant = torch.nonzero((self.count > 0) & (mean_grad > cfg.grad_threshold)).reshape(-1)
        room = min(cfg.max_points - points.num_points, math.ceil(cfg.densify_max_fraction * points.num_points))
        self._reset(points.num_points, points.X.device)
        if len(significant) == 0 or room <= 0:
            return 0
        if len(significant) > room:  # keep the strongest
            significant = significant[torch.topk(mean_grad[significant], room).indices]
        g = self.generator
        X = points.X.detach()
        alpha = points.alpha.detach()
        noise = torch.randn(len(significant), 3, generator=g).to(X) * cfg.spawn_std
        new_X = X[significant] + noise  # [M, 3]
        alpha_std = alpha.std(dim=0, keepdim=True) if len(alpha) > 1 else torch.ones_like(alpha[:1])
        new_alpha = torch.randn(len(significant), alpha.shape[1], generator=g).to(alpha) * alpha_std  # [M, D]
        update_points(points, optimizer, None, new_X, new_alpha)
        self._reset(points.num_points, X.device)
        return len(significant)

    def maybe_prune(self, step: int, points: AudioPoints, optimizer: torch.optim.Optimizer | None) -> int:
        """At pruning steps, remove radius outliers (Open3D); returns how many were removed.

        If the test would reject more than ``prune_max_fraction`` of the points, G_a is too
        sparse for the radius (e.g. a short stage 1) rather than full of outliers, and the
        step is skipped (the paper does not say; removing 97 % of a sparse cloud was measured
        to hurt).
        """
        cfg = self.cfg
        if not cfg.enabled or step <= 0 or step % cfg.prune_every:
            return 0
        keep = radius_inliers(points.X.detach().cpu(), cfg.prune_min_neighbors, cfg.prune_radius)
        n_keep = int(keep.sum())
        if n_keep == points.num_points or points.num_points - n_keep > cfg.prune_max_fraction * points.num_points:
            return 0
        removed = points.num_points - n_keep
        update_points(points, optimizer, keep.to(points.X.device))
        self._reset(points.num_points, points.X.device)
        return removed


def radius_inliers(X: torch.Tensor, min_neighbors: int, radius: float, backend: str = "auto") -> torch.Tensor:
    """bool [N]: points with at least ``min_neighbors`` other points within ``radius``.

    That is Open3D's ``remove_radius_outlier(nb_points, radius)`` rule, which the paper uses
    and which ``backend="open3d"`` calls. ``backend="scipy"`` applies the same rule with a
    k-d tree (``scipy.spatial.cKDTree``), for machines where Open3D cannot be installed
    (e.g. a minimal GPU image); a test pins the two to the same answer. ``"auto"`` prefers
    Open3D.
    """
    if backend not in ("auto", "open3d", "scipy"):
        raise ValueError(f"radius outlier backend must be 'auto', 'open3d' or 'scipy', got {backend!r}")
    pts = X.detach().double().cpu().numpy()  # [N, 3]
    if backend in ("auto", "open3d"):
        try:
            import open3d as o3d  # heavy; only when pruning
        except ImportError:
            if backend == "open3d":
                raise
        else:
            cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
            _, kept = cloud.remove_radius_outlier(nb_points=int(min_neighbors), radius=float(radius))
            keep = torch.zeros(len(X), dtype=torch.bool)
            keep[torch.as_tensor(list(kept), dtype=torch.long)] = True
            return keep
    from scipy.spatial import cKDTree

    counts = cKDTree(pts).query_ball_point(pts, r=float(radius), return_length=True)  # [N], self included
    return torch.as_tensor(counts - 1 >= int(min_neighbors))
