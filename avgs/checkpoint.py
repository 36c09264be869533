"""``scene.ckpt``: one versioned file holding everything inference and the viewer need.

A ``torch.save`` dict of tensors and plain values only, read back with
``torch.load(..., weights_only=True)`` (never unpickles code). Keys (ARCHITECTURE.md)::

    format_version  int, FORMAT_VERSION
    frame           {center [3], scale}           world <-> normalised map
    source          [3] tensor, normalised
    stft            {sample_rate, n_fft, hop_length, win_length}
    gaussians       optional: G's tensors (means [M,3] normalised, quats, log_scales,
                    opacity_logits, sh [M,16,3]); absent with --no-gaussians
    audio_points    {X [N,3] normalised, alpha [N,D]}
    field           F's state dict ({} for a --no-context model)
    binauralizer    B's state dict
    config          TrainConfig.to_dict()
    history         list of log records (dicts of plain values)
    scene           {name, bounds [2,3] world, outline [K,2,3] world segments (optional)}

Writes are atomic (temp file in the same folder, then ``os.replace``).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import torch

from avgs.atomic import torch_save
from avgs.config import STFT, STFTConfig, TrainConfig
from avgs.data.frame import SceneFrame

FORMAT_VERSION = 1
"Bumped whenever the layout of the checkpoint dict changes incompatibly."
REQUIRED_KEYS = ("format_version", "frame", "source", "stft", "audio_points", "field", "binauralizer", "config", "history", "scene")
"Top-level keys every checkpoint carries (``gaussians`` is optional)."


# -- writing ---------------------------------------------------------------------------


def save_checkpoint(ckpt: dict, path: str | Path) -> Path:
    """Write ``ckpt`` to ``path`` atomically; returns the path."""
    return torch_save(ckpt, path)


def _plain_state(module: torch.nn.Module | None) -> dict:
    if module is None:
        return {}
    return {k: v.detach().cpu().clone() for k, v in module.state_dict().items()}


def build_checkpoint(
    model,
    frame: SceneFrame,
    source_normalised,
    config: TrainConfig,
    *,
    history: list[dict] | None = None,
    gaussians: dict | None = None,
    name: str = "scene",
    bounds_world=None,
    outline_world=None,
    stft: STFTConfig = STFT,
    extra: dict | None = None,
) -> dict:
    """The checkpoint dict of a trained (or untrained) :class:`~avgs.acoustics.model.AVGSModel`.

    ``gaussians``: G as a dict of tensors (``GaussianModel.to_dict()``), or None.
    ``bounds_world`` defaults to the box around the audio points and the source.
    ``extra``: further top-level plain values (e.g. the stage-2 resume state).
    """
    X = model.points.X.detach().cpu().float().clone()  # [N, 3]
    alpha = model.points.alpha.detach().cpu().float().clone()  # [N, D]
    source = torch.as_tensor(np.asarray(source_normalised, dtype=np.float32)).reshape(3)
    if bounds_world is None:
        pts = frame.to_world(np.concatenate([X.numpy(), source.numpy()[None]]))
        bounds_world = np.stack([pts.min(0), pts.max(0)])
    scene = {"name": str(name), "bounds": torch.as_tensor(np.asarray(bounds_world, dtype=np.float32)).reshape(2, 3)}
    if outline_world is not None:
        scene["outline"] = torch.as_tensor(np.asarray(outline_world, dtype=np.float32)).reshape(-1, 2, 3)
    ckpt = {
        "format_version": FORMAT_VERSION,
        "frame": frame.to_dict(),
        "source": source,
        "stft": dataclasses.asdict(stft),
        "audio_points": {"X": X, "alpha": alpha},
        "field": _plain_state(model.field),
        "binauralizer": _plain_state(model.binauralizer),
        "config": config.to_dict(),
        "history": list(history or []),
        "scene": scene,
    }
    if gaussians is not None:
        ckpt["gaussians"] = {k: (v.detach().cpu().clone() if isinstance(v, torch.Tensor) else v) for k, v in gaussians.items()}
    if extra:
        ckpt.update(extra)
    return ckpt


def untrained_checkpoint(
    points_world,
    source_world,
    *,
    frame: SceneFrame | None = None,
    alpha=None,
    alpha_dim: int = 52,
    config: TrainConfig | None = None,
    seed: int = 0,
    name: str = "untrained",
    outline_world=None,
    gaussians: dict | None = None,
) -> dict:
    """A valid checkpoint with random network weights around given points (for tests and demos).

    points_world: [N, 3] world; source_world: [3] world. ``frame`` defaults to the map
    that puts the points' bounding box into [-1, 1]^3. ``alpha`` defaults to N(0, 1).
    """
    from avgs.acoustics.model import AVGSModel
    from avgs.acoustics.points import AudioPoints

    pts = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    if frame is None:
        lo, hi = pts.min(0), pts.max(0)
        frame = SceneFrame((lo + hi) / 2, 1.0 / max(float(np.max(hi - lo)) / 2, 1e-6))
    config = config or TrainConfig()
    g = torch.Generator().manual_seed(seed)
    if alpha is None:
        alpha = torch.randn(len(pts), alpha_dim, generator=g)
    torch.manual_seed(seed)
    model = AVGSModel(
        AudioPoints(torch.as_tensor(frame.to_normalised(pts), dtype=torch.float32), torch.as_tensor(alpha)),
        config.acoustic,
        config.stft,
    )
    # Heads that training starts at zero weight (a constant mask) get random weights here,
    # so that every output of an untrained model depends on the pose, as a trained one's does.
    b = model.binauralizer
    with torch.no_grad():
        for head in [b.mix_head] + ([b.reverb.head] if b.reverb is not None else []):
            bound = 1.0 / math.sqrt(head.in_features)
            head.weight.uniform_(-bound, bound)
    return build_checkpoint(
        model,
        frame,
        frame.to_normalised(source_world),
        config,
        gaussians=gaussians,
        name=name,
        outline_world=outline_world,
        stft=config.stft,
    )


# -- reading ---------------------------------------------------------------------------


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict:
    """Read and validate a checkpoint; errors name the file and what was expected."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # pickle / zip errors of a file that is not ours
        raise ValueError(
            f"{path}: not an AV-GS checkpoint (expected a torch.save file written by 'avgs train'): "
            f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        ) from None
    validate_checkpoint(ckpt, path)
    return ckpt


def validate_checkpoint(ckpt, path: str | Path = "<checkpoint>") -> None:
    """Raise ValueError naming ``path`` unless ``ckpt`` has the expected layout."""
    if not isinstance(ckpt, dict) or "format_version" not in ckpt:
        raise ValueError(f"{path}: not an AV-GS checkpoint (expected a dict with 'format_version')")
    version = ckpt["format_version"]
    if version != FORMAT_VERSION:
        raise ValueError(f"{path}: checkpoint format version {version!r}, this avgs reads version {FORMAT_VERSION}")
    missing = [k for k in REQUIRED_KEYS if k not in ckpt]
    if missing:
        raise ValueError(f"{path}: checkpoint is missing {', '.join(missing)} (expected keys: {', '.join(REQUIRED_KEYS)})")
    pts = ckpt["audio_points"]
    if not isinstance(pts, dict) or not {"X", "alpha"} <= set(pts):
        raise ValueError(f"{path}: 'audio_points' must hold 'X' [N,3] and 'alpha' [N,D]")
    X, alpha = pts["X"], pts["alpha"]
    if not (isinstance(X, torch.Tensor) and X.dim() == 2 and X.shape[1] == 3 and len(X) >= 1):
        raise ValueError(f"{path}: audio_points.X must be a tensor [N >= 1, 3]")
    if not (isinstance(alpha, torch.Tensor) and alpha.dim() == 2 and alpha.shape[0] == X.shape[0]):
        raise ValueError(f"{path}: audio_points.alpha must be a tensor [N={len(X)}, D]")
    try:
        SceneFrame.from_dict(ckpt["frame"])
    except ValueError as exc:
        raise ValueError(f"{path}: bad 'frame': {exc}") from None
    if not (isinstance(ckpt["source"], torch.Tensor) and ckpt["source"].numel() == 3):
        raise ValueError(f"{path}: 'source' must be a tensor of 3 numbers")
    try:
        TrainConfig.from_dict(ckpt["config"])
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: bad 'config': {exc}") from None
    scene = ckpt["scene"]
    if not isinstance(scene, dict) or "bounds" not in scene:
        raise ValueError(f"{path}: 'scene' must hold 'bounds' [2,3]")
    if "gaussians" in ckpt and ckpt["gaussians"] is not None:
        g = ckpt["gaussians"]
        if not isinstance(g, dict) or "means" not in g:
            raise ValueError(f"{path}: 'gaussians' must hold at least 'means' [M,3]")


def config_of(ckpt: dict) -> TrainConfig:
    """The training configuration stored in a checkpoint."""
    return TrainConfig.from_dict(ckpt["config"])


def stft_of(ckpt: dict) -> STFTConfig:
    """The STFT settings stored in a checkpoint."""
    known = {f.name for f in dataclasses.fields(STFTConfig)}
    return STFTConfig(**{k: v for k, v in ckpt["stft"].items() if k in known})


# -- scene outline ---------------------------------------------------------------------

_POLYGON_KEYS = ("corners", "vertices", "points", "polygon", "quad")


def outline_from_metadata(metadata: dict | None) -> np.ndarray | None:
    """Edges ``[K, 2, 3]`` (world, metres) of the room surfaces listed in scene.json, or None.

    Reads ``metadata["surfaces"]``: a list whose items are polygons (a list of [x, y, z]
    corners) or dicts holding one under ``corners`` / ``vertices`` / ``points`` /
    ``polygon`` / ``quad``. Each closed polygon contributes its edges; edges shared by
    two surfaces are kept once.
    """
    if not isinstance(metadata, dict):
        return None
    surfaces = metadata.get("surfaces")
    if surfaces is None and isinstance(metadata.get("room"), dict):
        surfaces = metadata["room"].get("surfaces")
    if not isinstance(surfaces, (list, tuple)):
        return None
    segments: dict[tuple, np.ndarray] = {}
    for s in surfaces:
        poly = s
        if isinstance(s, dict):
            poly = next((s[k] for k in _POLYGON_KEYS if k in s), None)
        try:
            corners = np.asarray(poly, dtype=np.float64)
        except (TypeError, ValueError):
            continue
        if corners.ndim != 2 or corners.shape[1] != 3 or len(corners) < 2 or not np.all(np.isfinite(corners)):
            continue
        for a, b in zip(corners, np.roll(corners, -1, axis=0)):
            key = tuple(sorted((tuple(np.round(a, 6)), tuple(np.round(b, 6)))))
            segments.setdefault(key, np.stack([a, b]))
    if not segments:
        return None
    return np.stack(list(segments.values()))  # [K, 2, 3]
