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
    binauralizer    B's state dict (the impulse-response task: the RIR network's,
                    :class:`~avgs.acoustics.rir_binauralizer.RIRBinauralizer`, with its mean
                    log magnitude and floor)
    task            optional: ``"binaural"`` (RWAVS: one source; the value of files without it)
                    or ``"rir"`` (impulse responses of many sources, ``avgs train --task rir``)
    rir             optional, task rir: {sources [S,3], receivers [R,3]} normalised, the training positions
    config          TrainConfig.to_dict()
    history         list of log records (dicts of plain values)
    scene           {name, bounds [2,3] world, outline [K,2,3] world segments (optional),
                    identity (optional): "sha256:<hex>" of the training scene (avgs.data.identity)}
    train_state     optional: the complete stage-2 training state (``Stage2Trainer.state_dict``)
    checksum        optional: ``"sha256:<hex>"`` of everything else (:func:`checkpoint_digest`),
                    written by :func:`save_checkpoint`; files without it (older ones) are read too

Writes are atomic (temp file in the same folder, then ``os.replace``).

Reading (:func:`load_checkpoint`) refuses every malformed file with one ``ValueError`` that
names the file and the problem, before any model is built from it: a file ``torch.load``
cannot read, contents that no longer match the stored checksum (a damaged copy), a missing
key, a wrong type, a tensor of the wrong shape for the stored configuration (the network
weights are compared with a model built from it on the ``meta`` device: no memory spent),
NaN or Inf, STFT settings out of range, a malformed training state (:mod:`avgs.io.checkpoint_format`). So whatever
:class:`avgs.render.renderer.SceneRenderer`, ``avgs info``, ``avgs prune`` and ``avgs train --resume``
do with a loaded checkpoint, they do it with a well-formed one.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import pickle
import struct
import math
import warnings
from pathlib import Path

import numpy as np
import torch

from avgs.config import STFT, STFTConfig, TrainConfig
from avgs.data.frame import SceneFrame
from avgs.io.atomic import torch_save
from avgs.io.checkpoint_format import CHECKSUM_KEY, FORMAT_VERSION, kind_of, validate_checkpoint



# -- writing ---------------------------------------------------------------------------


def save_checkpoint(ckpt: dict, path: str | Path) -> Path:
    """Write ``ckpt`` to ``path`` atomically, with its checksum (:func:`checkpoint_digest`); returns the path.

    ``ckpt`` itself is not changed; a ``checksum`` it carries (a loaded, edited checkpoint) is replaced.
    """
    data = {k: v for k, v in ckpt.items() if k != CHECKSUM_KEY}
    data[CHECKSUM_KEY] = checkpoint_digest(data)
    return torch_save(data, path)


def checkpoint_digest(ckpt: dict) -> str:
    """``"sha256:<hex>"`` of a checkpoint's contents (every key but ``checksum``): the values of its
    tensors (dtype, shape, bytes) and of its plain values, in a canonical order.

    What ``torch.load`` gives back from a file written by :func:`save_checkpoint` digests the
    same, so a file damaged after it was written (a flipped bit in a weight, which ``torch.load``
    itself does not notice) is refused by :func:`load_checkpoint`.
    """
    h = hashlib.sha256()
    _digest_into(h, {k: v for k, v in ckpt.items() if k != CHECKSUM_KEY})
    return "sha256:" + h.hexdigest()


def _digest_into(h, value) -> None:
    if isinstance(value, torch.Tensor):
        if value.layout != torch.strided:
            raise ValueError(f"a {value.layout} tensor (expected dense tensors)")
        t = value.detach().cpu().contiguous().reshape(-1)
        h.update(f"T{t.dtype}{tuple(value.shape)}".encode())
        if t.numel():
            h.update(t.view(torch.uint8).numpy().tobytes() if t.dtype != torch.uint8 else t.numpy().tobytes())
    elif isinstance(value, dict):
        h.update(f"D{len(value)}".encode())
        for key in sorted(value, key=lambda k: (type(k).__name__, repr(k))):
            h.update(f"K{type(key).__name__}:{key!r}".encode())
            _digest_into(h, value[key])
    elif isinstance(value, (list, tuple)):
        h.update(f"{'L' if isinstance(value, list) else 'U'}{len(value)}".encode())
        for item in value:
            _digest_into(h, item)
    elif isinstance(value, (set, frozenset)):
        h.update(f"S{len(value)}".encode())
        for r in sorted(repr(item) for item in value):
            h.update(r.encode())
    else:
        h.update(f"V{type(value).__name__}:{value!r}".encode())


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
    identity: str | None = None,
    bounds_world=None,
    outline_world=None,
    stft: STFTConfig = STFT,
    extra: dict | None = None,
) -> dict:
    """The checkpoint dict of a trained (or untrained) :class:`~avgs.acoustics.model.AVGSModel`.

    ``gaussians``: G as a dict of tensors (``GaussianModel.to_dict()``), or None.
    ``identity``: the training scene's :func:`avgs.data.identity.scene_identity` (``scene.identity``).
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
    if identity is not None:
        scene["identity"] = str(identity)
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
    """Read and validate a checkpoint; errors name the file and the problem.

    A missing file raises FileNotFoundError, an unreadable one (no permission, an I/O error)
    OSError; anything else wrong with it, ValueError (:func:`validate_checkpoint`). The
    returned dict holds no ``checksum`` (it was checked, and would not match an edited copy).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    if path.is_dir():
        raise ValueError(f"{path}: is a folder, not a checkpoint file")
    ckpt = load_weights_only(path, "an AV-GS checkpoint", map_location)
    if isinstance(ckpt, dict) and CHECKSUM_KEY in ckpt:
        stored = ckpt.pop(CHECKSUM_KEY)
        if not isinstance(stored, str):
            raise ValueError(f"{path}: damaged checkpoint ('{CHECKSUM_KEY}' is {kind_of(stored)}, expected a string)")
        try:
            actual = checkpoint_digest(ckpt)
        except ValueError as exc:
            raise ValueError(f"{path}: not an AV-GS checkpoint (it holds {exc})") from None
        if actual != stored:
            raise ValueError(
                f"{path}: damaged checkpoint (its contents do not match the checksum written with it; "
                "the file was changed or corrupted after it was saved)"
            )
    validate_checkpoint(ckpt, path)
    return ckpt


def load_weights_only(path: str | Path, what: str, map_location: str | torch.device = "cpu"):
    """``torch.load(path, weights_only=True)``: tensors and plain values, never code. A file that
    cannot be read so is one ``ValueError``: ``"{path}: not {what} (cannot be read as a torch.save
    file: REASON)"``, without torch's advice to load it with ``weights_only=False`` (for a file
    that carries code, the wrong advice). OS errors (permission, I/O) are ``OSError`` naming the file."""
    with open(path, "rb") as f:
        data = f.read()
    try:
        with warnings.catch_warnings():  # torch's warnings about odd pickles: the error says it
            warnings.simplefilter("ignore")
            return torch.load(io.BytesIO(data), map_location=map_location, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - whatever torch.load makes of bytes that are not such a file
        raise ValueError(f"{path}: not {what} (cannot be read as a torch.save file: {_load_error(exc)})") from None


def _load_error(exc: BaseException) -> str:
    """A short reason from ``torch.load``'s exception, without its advice about ``weights_only``."""
    text = str(exc)
    if "WeightsUnpickler error:" in text:
        detail = text.split("WeightsUnpickler error:", 1)[1]
        line = next((ln.strip() for ln in detail.splitlines() if ln.strip()), "")
        line = line.split(" Please use ", 1)[0].split(". ", 1)[0].rstrip(".")
        if line.startswith("Unsupported global"):
            return f"it holds objects other than tensors and plain values ({line})"
        return f"not a pickle of tensors and plain values ({line or 'unreadable pickle'})"
    if isinstance(exc, EOFError) or not text.strip():
        return f"the file is empty or ends too early ({type(exc).__name__})"
    if isinstance(exc, (IndexError, KeyError, pickle.UnpicklingError, struct.error)):  # "pop from empty list", ...
        return "its bytes are not a torch.save file (a pickle that breaks off or was never one)"
    line = next((ln.strip() for ln in text.splitlines() if ln.strip()), "")
    line = line.split(". ", 1)[0].rstrip(".")
    if "weights_only" in line or "Weights only" in line:
        line = "unreadable contents"
    if len(line) > 160:
        line = line[:157] + "..."
    return f"{type(exc).__name__}: {line}"


def config_of(ckpt: dict) -> TrainConfig:
    """The training configuration stored in a checkpoint."""
    return TrainConfig.from_dict(ckpt["config"])


def stft_of(ckpt: dict) -> STFTConfig:
    """The STFT settings stored in a checkpoint."""
    known = {f.name for f in dataclasses.fields(STFTConfig)}
    return STFTConfig(**{k: v for k, v in ckpt["stft"].items() if k in known})
