"""RGB key frames of a scene spec, rendered off-screen with PyVista (EGL, no display).

Each visible surface is drawn in its material's colour, with a fixed per-surface shade
(from a fixed light direction, so colours do not change with the viewpoint, as 3D-GS
assumes) and a faint 25 cm tile pattern (so that views can be told apart on large plain
walls). Lighting is off. The source is drawn as a small dark loudspeaker box. Open
boundaries (outdoor sky) are not drawn; the background takes the sky colour.

The camera stands at the listener's ear position, looks along its facing (level), +z
up, with a vertical field of view ``fov_deg`` (``camera.view_angle``).
"""

from __future__ import annotations

import math

import numpy as np

from avgs.synth.materials import SKY_COLOR, SOURCE_COLOR, material_info
from avgs.synth.presets import SceneSpec, Surface

LIGHT = np.array([0.35, 0.55, 0.76]) / np.linalg.norm([0.35, 0.55, 0.76])
TILE = 0.25
SPEAKER_SIZE = np.array([0.25, 0.25, 0.35])


def surface_shade(corners: np.ndarray) -> float:
    """Brightness factor in [0.7, 1] of a planar polygon ``[K, 3]`` under the fixed light."""
    n = np.cross(corners[1] - corners[0], corners[2] - corners[0])
    n = n / max(float(np.linalg.norm(n)), 1e-12)
    return 0.7 + 0.3 * abs(float(np.dot(n, LIGHT)))


def _surface_mesh(surface: Surface, rng: np.random.Generator):
    """A tiled quad mesh with per-cell RGB (uint8) for one planar convex polygon."""
    import pyvista as pv

    c = np.asarray(surface.corners, dtype=np.float64)
    base = np.asarray(material_info(surface.material).color) * surface_shade(c)
    if len(c) == 4:
        u_len, v_len = np.linalg.norm(c[1] - c[0]), np.linalg.norm(c[3] - c[0])
        nu, nv = max(1, math.ceil(u_len / TILE)), max(1, math.ceil(v_len / TILE))
        s, t = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
        pts = (
            (1 - s)[..., None] * (1 - t)[..., None] * c[0]
            + s[..., None] * (1 - t)[..., None] * c[1]
            + s[..., None] * t[..., None] * c[2]
            + (1 - s)[..., None] * t[..., None] * c[3]
        )  # [nu+1, nv+1, 3]
        mesh = pv.StructuredGrid(pts[..., 0], pts[..., 1], pts[..., 2]).extract_surface(algorithm=None)
    else:
        faces = np.concatenate([[len(c)], np.arange(len(c))])
        mesh = pv.PolyData(c, faces)
    jitter = rng.uniform(0.93, 1.07, size=(mesh.n_cells, 1))
    mesh.cell_data["rgb"] = (np.clip(base * jitter, 0, 1) * 255).astype(np.uint8)
    return mesh


class FrameRenderer:
    """Renders ``[height, width, 3]`` uint8 frames of one scene from listener poses.

    Build once per scene (meshes and the off-screen plotter), call :meth:`render` per
    pose, :meth:`close` at the end (or use it as a context manager).
    """

    def __init__(self, spec: SceneSpec, width: int, height: int, fov_deg: float, seed: int = 0):
        import pyvista as pv

        _quiet_vtk()
        self.width, self.height, self.fov_deg = int(width), int(height), float(fov_deg)
        rng = np.random.default_rng([int(seed), 20])
        self.plotter = pv.Plotter(off_screen=True, window_size=(self.width, self.height))
        self.plotter.set_background(SKY_COLOR)
        for surface in spec.visible_surfaces():
            self.plotter.add_mesh(_surface_mesh(surface, rng), scalars="rgb", rgb=True, lighting=False, show_edges=False)
        src = np.asarray(spec.source, dtype=np.float64)
        speaker = pv.Box(bounds=np.ravel(np.column_stack([src - SPEAKER_SIZE / 2, src + SPEAKER_SIZE / 2])))
        self.plotter.add_mesh(speaker, color=SOURCE_COLOR, lighting=False)
        self.plotter.camera.view_angle = self.fov_deg
        far = float(np.linalg.norm(np.ptp(spec.bounds(), axis=0))) * 2
        self._clip = (0.05, max(far, 10.0))

    def render(self, position, yaw_deg: float) -> np.ndarray:
        """The view from ``position`` ([3] world) facing ``yaw_deg`` (ccw from +x): ``[H, W, 3]`` uint8."""
        p = np.asarray(position, dtype=np.float64)
        a = math.radians(yaw_deg)
        cam = self.plotter.camera
        cam.position = tuple(p)
        cam.focal_point = tuple(p + np.array([math.cos(a), math.sin(a), 0.0]))
        cam.up = (0.0, 0.0, 1.0)
        cam.view_angle = self.fov_deg
        cam.clipping_range = self._clip
        self.plotter.camera_set = True  # keep PyVista from resetting the camera to fit the scene
        self.plotter.render()
        img = self.plotter.screenshot(return_img=True)
        return np.ascontiguousarray(img[..., :3])

    def close(self) -> None:
        self.plotter.close()

    def __enter__(self) -> "FrameRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _quiet_vtk() -> None:
    """Silence VTK's 'bad X server connection' notice when it falls back to EGL."""
    try:
        import vtk

        vtk.vtkLogger.SetStderrVerbosity(vtk.vtkLogger.VERBOSITY_OFF)
        vtk.vtkObject.GlobalWarningDisplayOff()
    except (ImportError, AttributeError):
        pass


def focal_length_px(height: int, fov_deg: float) -> float:
    """Pinhole focal length in pixels for a vertical field of view (square pixels)."""
    return 0.5 * height / math.tan(math.radians(fov_deg) / 2)
