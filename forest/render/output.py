"""A rendered frame and how it is written: the comp-ready EXR and the display PNG.

Both renderers (:mod:`forest.render.frame`, ``scalar_rgb``; :mod:`forest.render.jit_frame`,
forest_path) return a :class:`FrameImage`; :func:`write_frame` writes it with
:mod:`forest.imaging`:

* the EXR (:func:`forest.imaging.write_comp_exr`): ``R G B`` the beauty
  (scene-linear Rec.709, sky and haze included), ``A`` the coverage of
  geometry (the fraction of a pixel's camera samples that met a surface;
  0 where only sky is seen), ``depth.Z`` / ``id.Z`` / ``species.Z`` from one
  ray through each pixel centre, ``CryptoObject`` (per tree, names
  ``<species>/<tree id>``, and ``terrain``) and ``CryptoAsset`` (per species)
  Cryptomattes from per-sample ids, the comp AOVs of ``[render] aovs``
  (``N``, ``P``, ``albedo``, ``forward`` motion vectors, ``lightgroup.*``; see
  :mod:`forest.render.path.aovs`), ``worldToCamera`` / ``worldToNDC``, the
  colour space (``chromaticities``, ``colorInteropID``), the species-name
  table, and forest's settings and statistics (``forest:*``);
* the PNG (:func:`forest.imaging.write_display`): the beauty through
  ``[render] view`` at ``[render] exposure``.

With ``[render] working_space = "acescg"`` the EXR's beauty and colour layers are converted
from the renderer's linear Rec.709 to ACEScg and its header says so
(:mod:`forest.imaging.working_space`); the PNG is made from the Rec.709 beauty, unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import CameraState
from ..imaging import camera_matrices, write_comp_exr, write_display
from ..imaging.cryptomatte import Cryptomatte
from ..imaging.exr import AOV_CHANNELS
from ..imaging.working_space import from_rec709


@dataclass
class FrameImage:
    """One rendered frame: the beauty and everything written beside it."""

    rgb: np.ndarray  # (H, W, 3) float32, scene-linear (denoised when ``denoised``)
    alpha: np.ndarray  # (H, W) float32, coverage of geometry
    depth: np.ndarray  # (H, W) float32, metres to the first opaque hit; the far clip where none
    id: np.ndarray  # (H, W) float32, tree id, -1 none
    species: np.ndarray  # (H, W) float32, species index, -1 none
    camera: CameraState
    levels: np.ndarray
    mattes: list[Cryptomatte] = field(default_factory=list)
    albedo: np.ndarray | None = None  # (H, W, 3) first-hit albedo (denoiser guide)
    normal: np.ndarray | None = None  # (H, W, 3) first-hit shading normal
    denoised: bool = False
    aovs: dict[str, np.ndarray] = field(default_factory=dict)  # comp layers, name → (H, W, C) ([render] aovs)


def header_value(v: Any) -> Any:
    """A value as an EXR header attribute (ints, floats and strings; bools as 0/1)."""
    if isinstance(v, (bool, np.bool_)):
        return int(v)
    if isinstance(v, (int, np.integer)):
        return int(v) if -(2**31) <= int(v) < 2**31 else str(int(v))
    if isinstance(v, (float, np.floating)):
        return float(v)
    return str(v)


def write_frame(
    exr: Path,
    png: Path,
    image: FrameImage,
    *,
    species_names: list[str],
    near: float,
    far: float,
    view: str,
    exposure: float,
    attributes: dict[str, Any],
    working_space: str = "rec709",
    look: str = "none",
) -> list[Path]:
    """Write ``image`` as its EXR (in ``working_space``) and PNG (see the module docstring); the paths written."""
    h, w = image.rgb.shape[:2]
    cam = image.camera
    matrices = camera_matrices(cam.position, cam.target, cam.up, cam.fov, w, h, near=near, far=far)
    attrs = {k: header_value(v) for k, v in attributes.items()}
    attrs["forest:view"] = view
    attrs["forest:exposure"] = float(exposure)
    if look != "none":
        attrs["forest:look"] = look
    aovs = {
        name: from_rec709(a, working_space) if AOV_CHANNELS.get(name, ("R", "G", "B")) == ("R", "G", "B") else a
        for name, a in image.aovs.items()
    }
    write_comp_exr(
        exr,
        from_rec709(image.rgb, working_space),
        alpha=image.alpha,
        depth=image.depth,
        tree_id=image.id,
        species=image.species,
        species_names=species_names,
        mattes=image.mattes,
        camera=matrices,
        attributes=attrs,
        aovs=aovs,
        working_space=working_space,
    )
    try:
        write_display(png, image.rgb, view=view, exposure=exposure, look=look)
    except BaseException:
        exr.unlink(missing_ok=True)  # the frame is the pair: no EXR left without its PNG
        raise
    return [exr, png]
