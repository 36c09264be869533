"""Camera views for stage 1 (the 3D-GS warm-up): RGB key frames with their poses and
pinhole intrinsics, from a scene folder in the RWAVS layout (docs/design.md, "Data layout (RWAVS)").

- Images: ``frames/NNNNN.png`` (the entry's ``file_path``, else ``frames/<its name>``).
- Poses: ``transforms_scale_{split}.json`` (normalised frame, as the audio model uses);
  without it, ``transforms_{split}.json`` mapped to the normalised frame, exactly as
  :class:`avgs.data.rwavs.RWAVSScene` reads them (:func:`avgs.data.pose_files.read_scene_poses`:
  every transforms file present checked against the others, the other split's too).
  Nerfstudio camera-path entries: ``camera_to_world`` 16 floats row-major, OpenGL camera
  (looks along -Z, +Y up).
- Intrinsics, first found: ``transforms.json``'s ``fl_x, fl_y, cx, cy, w, h`` (scaled to
  the image's real size; pixels no more than 2:1, the principal point inside the frame, and
  warned when not square or off the entries' ``fov``: :func:`avgs.data.consistency.check_intrinsics`);
  the entry's ``fov`` (vertical, degrees; square pixels, centred principal point); else
  :data:`DEFAULT_FOV_DEG` with a warning.

Validated as :mod:`avgs.data.rwavs` validates (JSON, numbers, rigid poses, frames listed
once and inside the scene folder); images are refused by name when they are no regular
file, undecodable (any PIL error) or larger than :data:`MAX_IMAGE_SIDE` /
:data:`MAX_IMAGE_PIXELS` (checked from the header, before decoding), and the camera
matrices must come out finite in float32.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from avgs.data.consistency import check_intrinsics
from avgs.data.files import file_present, finite_number, is_regular_file, read_json, require_file
from avgs.data.pose_files import SPLITS, frame_number_of, read_scene_metadata, read_scene_poses, transforms_path

INTRINSICS_FILE = "transforms.json"
DEFAULT_FOV_DEG = 60.0
"Vertical field of view (degrees) assumed for a scene that states no intrinsics."
MAX_IMAGE_SIDE = 16384
"Widest / tallest key frame accepted, in pixels (16K)."
MAX_IMAGE_PIXELS = 64 * 2**20
"""Most pixels a key frame may have (64 Mpx: an 8K frame is 33 Mpx), checked from the
header before decoding; below PIL's own decompression-bomb limit (89 Mpx), which is
enforced too."""


@dataclass(frozen=True, eq=False)
class Views:
    """``V`` posed RGB views of one scene (normalised frame)."""

    images: torch.Tensor  # [V, H, W, 3] float32 in [0, 1]
    c2w: torch.Tensor  # [V, 4, 4] float32, OpenGL camera-to-world
    K: torch.Tensor  # [V, 3, 3] float32, pixels at this resolution (pixel centres at +0.5)
    frame_numbers: list[int] = field(default_factory=list)
    paths: list[Path] = field(default_factory=list)
    root: Path | None = None  # the scene folder, when loaded from one
    split: str | None = None

    def __post_init__(self) -> None:
        V = self.images.shape[0]
        if self.images.dim() != 4 or self.images.shape[-1] != 3:
            raise ValueError(f"Views: images must be [V, H, W, 3], got {list(self.images.shape)}")
        if tuple(self.c2w.shape) != (V, 4, 4) or tuple(self.K.shape) != (V, 3, 3):
            raise ValueError(f"Views: c2w must be [{V}, 4, 4] and K [{V}, 3, 3], got {list(self.c2w.shape)}, {list(self.K.shape)}")

    def __len__(self) -> int:
        return int(self.images.shape[0])

    @property
    def height(self) -> int:
        return int(self.images.shape[1])

    @property
    def width(self) -> int:
        return int(self.images.shape[2])

    @property
    def device(self) -> torch.device:
        return self.images.device

    def camera_centers(self) -> torch.Tensor:
        """``[V, 3]`` camera positions."""
        return self.c2w[:, :3, 3]

    def scene_extent(self) -> float:
        """3D-GS's scene scale: 1.1 x the largest distance of a camera from the cameras'
        mean (at least 0.1, so that a single camera or a turn on the spot still gets one)."""
        c = self.camera_centers().double()
        radius = float((c - c.mean(0)).norm(dim=-1).max()) if len(c) else 0.0
        return max(1.1 * radius, 0.1)

    def subset(self, index) -> "Views":
        """The views at ``index`` (a list or tensor of ints)."""
        idx = torch.as_tensor(index, dtype=torch.long).reshape(-1)
        picked = idx.tolist()
        return replace(
            self,
            images=self.images[idx.to(self.images.device)],
            c2w=self.c2w[idx.to(self.c2w.device)],
            K=self.K[idx.to(self.K.device)],
            frame_numbers=[self.frame_numbers[i] for i in picked] if self.frame_numbers else [],
            paths=[self.paths[i] for i in picked] if self.paths else [],
        )

    def downscaled(self, factor: int) -> "Views":
        """Images shrunk ``factor`` times by area averaging (sizes rounded down), K to match."""
        factor = int(factor)
        if factor < 1:
            raise ValueError(f"downscale factor must be an integer >= 1, got {factor}")
        if factor == 1:
            return self
        return replace(self, images=_downscale(self.images, factor), K=_scale_K(self.K, self.width, self.height, factor))

    def to(self, device) -> "Views":
        return replace(self, images=self.images.to(device), c2w=self.c2w.to(device), K=self.K.to(device))


def _downscale(images: torch.Tensor, factor: int) -> torch.Tensor:
    """``[V, H, W, 3]`` -> ``[V, H // factor, W // factor, 3]`` (area average)."""
    V, H, W, _ = images.shape
    h, w = max(1, H // factor), max(1, W // factor)
    x = images.permute(0, 3, 1, 2)
    return F.interpolate(x, size=(h, w), mode="area").permute(0, 2, 3, 1).contiguous()


def _scale_K(K: torch.Tensor, width: int, height: int, factor: int) -> torch.Tensor:
    sx = max(1, width // factor) / width
    sy = max(1, height // factor) / height
    out = K.clone()
    out[:, 0] *= sx
    out[:, 1] *= sy
    return out


_read_json = read_json  # the name this module used before


def _read_image(path: Path) -> np.ndarray:
    """``[H, W, 3]`` float32 in [0, 1]."""
    from PIL import Image

    require_file(path, "the key frame named by the transforms file")
    with warnings.catch_warnings():
        warnings.simplefilter("error", Image.DecompressionBombWarning)
        try:
            im = Image.open(path)
        except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
            raise ValueError(f"{path}: image too large to decode safely ({exc})") from None
        except Exception as exc:  # PIL's errors are many and undocumented: all mean "not an image we can read"
            raise ValueError(f"{path}: not a readable image ({type(exc).__name__}: {str(exc)[:200]})") from None
        with im:
            W, H = im.size
            if not (0 < W <= MAX_IMAGE_SIDE and 0 < H <= MAX_IMAGE_SIDE and W * H <= MAX_IMAGE_PIXELS):
                raise ValueError(
                    f"{path}: image declares {W}x{H} pixels; a key frame may be at most "
                    f"{MAX_IMAGE_SIDE} pixels a side and {MAX_IMAGE_PIXELS} pixels in all"
                )
            try:
                rgb = np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
            except Exception as exc:
                raise ValueError(f"{path}: not a readable image ({type(exc).__name__}: {str(exc)[:200]})") from None
    if rgb.ndim != 3 or rgb.shape[:2] != (H, W) or not np.all(np.isfinite(rgb)):
        raise ValueError(f"{path}: not a readable image (decoded to {list(rgb.shape)} values, expected {H}x{W}x3 finite)")
    return rgb


def _file_intrinsics(root: Path):
    """(fl_x, fl_y, cx, cy, w, h) from ``transforms.json``, or None when it is absent or has none."""
    path = root / INTRINSICS_FILE
    what = "nerfstudio transforms with fl_x, fl_y, cx, cy, w, h"
    if not file_present(path, what):
        return None
    meta = read_json(path, what)
    keys = ("fl_x", "fl_y", "cx", "cy", "w", "h")
    if not isinstance(meta, dict) or not all(k in meta for k in keys):
        if isinstance(meta, dict) and any(k in meta for k in keys):
            raise ValueError(f"{path}: has some but not all of {', '.join(keys)}")
        return None
    vals = tuple(finite_number(meta[k], f"{path}: {k}") for k in keys)
    if not all(math.isfinite(v) for v in vals) or min(vals[0], vals[1], vals[4], vals[5]) <= 0:
        raise ValueError(f"{path}: fl_x, fl_y, w, h must be finite and > 0, got {vals}")
    return vals


def _entry_fovs(path: Path) -> dict[int, float]:
    """Frame number -> vertical FOV (degrees) for camera-path entries that carry ``fov``."""
    meta = read_json(path, "a camera path")
    out = {}
    for i, entry in enumerate(meta.get("camera_path", []) if isinstance(meta, dict) else []):
        if isinstance(entry, dict) and "fov" in entry and "file_path" in entry:
            fov = finite_number(entry["fov"], f"{path}: camera_path[{i}].fov (degrees)")
            if not 0 < fov < 180:
                raise ValueError(f"{path}: camera_path[{i}] fov must be in (0, 180) degrees, got {fov}")
            out[frame_number_of(entry["file_path"], f"{path}: camera_path[{i}]")] = fov
    return out


def _poses(root: Path, split: str):
    """(entries, their normalised c2w [V, 4, 4], the file read): every transforms file of the
    scene read and checked against the others, as the audio loader does
    (:func:`avgs.data.pose_files.read_scene_poses`), the other split's too where present."""
    poses = read_scene_poses(root, read_scene_metadata(root), every_split=False)
    if split not in poses.entries:
        scaled, plain = transforms_path(root, split, True), transforms_path(root, split, False)
        raise FileNotFoundError(f"{scaled}: missing; expected it or {plain.name} with the {split} camera poses")
    entries = poses.entries[split]
    return [e for e, _ in entries], [c2w for _, c2w in entries], poses.files[split]


def load_views(scene_root: str | Path, split: str, downscale: int = 1) -> Views:
    """The posed key frames of one split (``"train"`` or ``"val"``) of a scene folder.

    ``downscale`` shrinks every image by that integer factor as it is read (area average).
    """
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    if int(downscale) != downscale or downscale < 1:
        raise ValueError(f"downscale must be an integer >= 1, got {downscale!r}")
    downscale = int(downscale)
    root = Path(scene_root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: scene folder missing")
    entries, poses, source = _poses(root, split)
    if not entries:
        raise ValueError(f"{source}: no posed frames in the {split} split")
    fovs = _entry_fovs(source)
    file_k = _file_intrinsics(root)
    images, Ks, paths, size = [], [], [], None
    warned = False
    for entry in entries:
        path = root / entry.file_path
        if not is_regular_file(path):
            path = root / "frames" / Path(entry.file_path.replace("\\", "/")).name
        img = _read_image(path)
        H, W = img.shape[:2]
        if size is None:
            size = (H, W)
        elif (H, W) != size:
            raise ValueError(f"{path}: image is {W}x{H}, the split's first frame {paths[0]} is {size[1]}x{size[0]}")
        if file_k is not None:
            fx, fy, cx, cy, w, h = file_k
            sx, sy = W / w, H / h
            K = [[fx * sx, 0, cx * sx], [0, fy * sy, cy * sy], [0, 0, 1]]
        else:
            fov = fovs.get(entry.frame_number)
            if fov is None:
                fov = DEFAULT_FOV_DEG
                if not warned:
                    warnings.warn(
                        f"{root}: no intrinsics ({INTRINSICS_FILE} or a 'fov' in {source.name}); "
                        f"assuming a vertical field of view of {DEFAULT_FOV_DEG} degrees",
                        UserWarning,
                        stacklevel=2,
                    )
                    warned = True
            f = 0.5 * H / math.tan(math.radians(fov) / 2)
            K = [[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]]
        t = torch.from_numpy(img)
        if downscale > 1:
            t = _downscale(t[None], downscale)[0]
        images.append(t)
        Ks.append(K)
        paths.append(path)
    K = torch.tensor(Ks, dtype=torch.float32)
    if downscale > 1:
        K = _scale_K(K, size[1], size[0], downscale)
    if not bool(torch.isfinite(K).all()) or bool((K[:, 0, 0] <= 0).any()) or bool((K[:, 1, 1] <= 0).any()):
        named = root / INTRINSICS_FILE if file_k is not None else source
        raise ValueError(f"{named}: the intrinsics give a camera matrix that is not finite (or a focal length <= 0) in float32")
    if file_k is not None:
        fov = next(((k, fovs[k]) for k in (e.frame_number for e in entries) if k in fovs), None)
        stated = None if fov is None else (source, f"frame {fov[0]}'s fov", fov[1])
        check_intrinsics(root / INTRINSICS_FILE, Ks[0], size[1], size[0], stated)
    return Views(
        images=torch.stack(images),
        c2w=torch.from_numpy(np.stack(poses)).float(),
        K=K,
        frame_numbers=[e.frame_number for e in entries],
        paths=paths,
        root=root,
        split=split,
    )
