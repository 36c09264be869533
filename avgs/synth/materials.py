"""Acoustic materials of the synthetic scenes and the colour each one is drawn in.

Absorption coefficients come from pyroomacoustics' table (``pra.materials_data``, octave
bands 125 Hz - 8 kHz); ``open`` is our own: a nearly anechoic boundary standing for open
sky or open space (outdoor scenes), never drawn. Colours are distinct per material so that
the key frames (and the Gaussians fitted to them) carry material information, as the
AV-GS paper assumes.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class MaterialInfo:
    """One material: where its absorption comes from, how it scatters, how it is drawn."""

    absorption: str | float  # a key of pra.materials_data's absorption tables, or a flat coefficient
    color: tuple[float, float, float]  # display RGB in [0, 1]
    scattering: float = 0.1  # flat scattering coefficient (ray tracing)
    visible: bool = True  # False: an acoustic boundary only (not drawn, not a surface point)


MATERIALS: dict[str, MaterialInfo] = {
    # walls and ceilings
    "plasterboard": MaterialInfo("plasterboard", (0.86, 0.84, 0.78)),
    "brickwork": MaterialInfo("brickwork", (0.66, 0.33, 0.24), 0.2),
    "rough_concrete": MaterialInfo("rough_concrete", (0.55, 0.55, 0.53), 0.2),
    "glass_window": MaterialInfo("glass_window", (0.55, 0.75, 0.86), 0.05),
    "wooden_lining": MaterialInfo("wooden_lining", (0.72, 0.55, 0.35), 0.1),
    "curtains_velvet": MaterialInfo("curtains_velvet", (0.55, 0.12, 0.18), 0.3),
    "ceiling_fissured_tile": MaterialInfo("ceiling_fissured_tile", (0.95, 0.95, 0.92), 0.2),
    "ceiling_plasterboard": MaterialInfo("ceiling_plasterboard", (0.97, 0.96, 0.93)),
    "rockwool_50mm_40kgm3": MaterialInfo("rockwool_50mm_40kgm3", (0.35, 0.45, 0.60), 0.3),
    # floors
    "carpet_cotton": MaterialInfo("carpet_cotton", (0.30, 0.36, 0.52), 0.2),
    "carpet_hairy": MaterialInfo("carpet_hairy", (0.45, 0.55, 0.35), 0.3),
    "wood_16mm": MaterialInfo("wood_16mm", (0.60, 0.42, 0.25)),
    "ceramic_tiles": MaterialInfo("ceramic_tiles", (0.80, 0.80, 0.84), 0.05),
    "linoleum_on_concrete": MaterialInfo("linoleum_on_concrete", (0.48, 0.62, 0.58)),
    # furniture
    "chairs_upholstered_cloth": MaterialInfo("chairs_upholstered_cloth", (0.25, 0.50, 0.45), 0.5),
    "wood_1.6cm": MaterialInfo("wood_1.6cm", (0.45, 0.28, 0.15), 0.3),
    "wooden_door": MaterialInfo("wooden_door", (0.52, 0.35, 0.22), 0.2),
    # open boundary (outdoor): nearly anechoic, never drawn
    "open": MaterialInfo(1.0, (0.62, 0.78, 0.95), 0.0, visible=False),
}
SKY_COLOR = MATERIALS["open"].color
SOURCE_COLOR = (0.08, 0.08, 0.08)
"The loudspeaker box drawn at the source (visual only)."


def material_info(name: str) -> MaterialInfo:
    """The entry of :data:`MATERIALS` named ``name`` (a clear error otherwise)."""
    try:
        return MATERIALS[name]
    except KeyError:
        raise ValueError(f"unknown material {name!r}; expected one of {', '.join(sorted(MATERIALS))}") from None


def pra_material(name: str):
    """A ``pyroomacoustics.Material`` for ``name`` (multi-band absorption, flat scattering)."""
    import pyroomacoustics as pra

    info = material_info(name)
    return pra.Material(energy_absorption=info.absorption, scattering=info.scattering)


def absorption_table(name: str) -> dict:
    """``{"center_freqs": [Hz], "coeffs": [...]}`` of a material, for scene.json."""
    import pyroomacoustics as pra

    info = material_info(name)
    if isinstance(info.absorption, str):
        for table in pra.materials_data["absorption"].values():
            if info.absorption in table:
                coeffs = list(table[info.absorption]["coeffs"])
                freqs = list(pra.materials_data["center_freqs"][: len(coeffs)])
                return {"center_freqs": freqs, "coeffs": coeffs}
        raise ValueError(f"material {name!r}: {info.absorption!r} is not in pyroomacoustics' materials table")
    return {"center_freqs": [], "coeffs": [float(info.absorption)]}


def material_record(name: str) -> dict:
    """Everything scene.json stores about one material."""
    info = material_info(name)
    return {
        "absorption": absorption_table(name),
        "scattering": info.scattering,
        "color": list(info.color),
        "visible": info.visible,
        "source": "pyroomacoustics.materials_data" if isinstance(info.absorption, str) else "avgs (open boundary)",
    }
