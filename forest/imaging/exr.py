"""The comp-ready EXR of a frame: beauty with alpha, data layers, Cryptomattes and a header a compositor trusts.

One single-part EXR (lossless ZIP at zlib level 1, float32 unless asked) with these channels:

==========================  =====================================================================
``R, G, B, A``              scene-linear beauty (Rec.709 primaries, D65) with alpha = coverage of
                            geometry (everything but the sky / background)
``background.R, G, B``      (optional) the sky seen directly; then ``RGB`` holds the foreground
                            only, premultiplied by ``A``, and ``RGB + background = beauty``
``depth.Z``                 distance along the camera ray to the first hit, metres
``id.Z``                    tree id (InstanceSet ``id``, exact up to 2²⁴), −1 where no tree
``species.Z``               species index into the header's ``forest:species_names``, −1 none
``CryptoObject00 … .RGBA``  Cryptomatte of individual trees (names ``<species>/<tree id>``)
``CryptoAsset00 … .RGBA``   Cryptomatte of species (names = species names)
``N.X, N.Y, N.Z``           (optional AOVs) first-hit shading normal, world space, unit length
``P.X, P.Y, P.Z``           world position of the pixel-centre hit, metres
``albedo.R, G, B``          first-hit albedo
``forward.u, forward.v``    motion vectors, pixels, u right, v up (Nuke's ``forward`` layer)
``lightgroup.<g>.R, G, B``  the beauty's light from group g (sun, sky, haze): Σ_g = beauty
==========================  =====================================================================

Header (besides the caller's ``forest:*`` attributes):

- ``chromaticities`` — Rec.709 primaries and D65 white (OpenEXR standard attribute);
- ``colorInteropID`` = ``lin_rec709_scene`` — the Color Interop Forum name of the
  colour space, which forest's OCIO config and OCIO's built-in studio config
  (``ocio://studio-config-latest``) both resolve to ``Linear Rec.709 (sRGB)``;
  written through OpenImageIO's ``oiio:ColorSpace``; with ``working_space="acescg"`` the
  AP1 primaries and ACES white and ``lin_ap1_scene`` (:mod:`forest.imaging.working_space`);
- ``worldToCamera``, ``worldToNDC`` — see :mod:`forest.imaging.camera_matrices`;
- ``forest:species_names`` — JSON list, index = the ``species`` channel's value;
- ``cryptomatte/<key>/…`` — see :mod:`forest.imaging.cryptomatte`;
- ``forest:layers`` — a one-line description of the channels above.

Same inputs ⇒ byte-identical file (no time stamps, sorted attributes, sorted manifest).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from ..images import write_exr_channels
from .camera_matrices import CameraMatrices
from .cryptomatte import Cryptomatte
from .ocio_config import SCENE_LINEAR_INTEROP_ID

REC709_CHROMATICITIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
"""OpenEXR ``chromaticities``: red xy, green xy, blue xy, white xy (ITU-R BT.709, D65)."""

AOV_CHANNELS: dict[str, tuple[str, ...]] = {
    "N": ("X", "Y", "Z"),
    "P": ("X", "Y", "Z"),
    "albedo": ("R", "G", "B"),
    "forward": ("u", "v"),
}
"""Channel names of the comp AOV layers (:func:`write_comp_exr`'s ``aovs``); any other 3-channel layer is R, G, B."""

FLOAT32_EXACT = 2**24
"""Integers up to this are exact in the float32 ``id.Z`` / ``species.Z`` channels."""


def colour_space_header(working_space: str = "rec709") -> dict[str, object]:
    """The colour-space attributes of a scene-linear EXR in ``working_space`` (``rec709`` or ``acescg``, see
    :mod:`forest.imaging.working_space`): ``chromaticities`` and the ``colorInteropID``."""
    if working_space == "rec709":
        return {"chromaticities": REC709_CHROMATICITIES, "oiio:ColorSpace": SCENE_LINEAR_INTEROP_ID}
    from .working_space import INTEROP_IDS, check_working_space, chromaticities

    return {
        "chromaticities": chromaticities(check_working_space(working_space)),
        "oiio:ColorSpace": INTEROP_IDS[working_space],
    }


def _plane(name: str, arr: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    if arr is None:
        return None
    a = np.asarray(arr, dtype=np.float32)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if a.shape != shape:
        raise ValueError(f"{name} is {a.shape}, the beauty is {shape}")
    return a


def write_comp_exr(
    path: str | Path,
    beauty: np.ndarray,
    *,
    alpha: np.ndarray | None = None,
    background: np.ndarray | None = None,
    depth: np.ndarray | None = None,
    tree_id: np.ndarray | None = None,
    species: np.ndarray | None = None,
    species_names: Sequence[str] = (),
    mattes: Sequence[Cryptomatte] = (),
    camera: CameraMatrices | None = None,
    attributes: Mapping[str, object] | None = None,
    half_beauty: bool = False,
    aovs: Mapping[str, np.ndarray] | None = None,
    working_space: str = "rec709",
) -> Path:
    """Write a frame's comp-ready EXR atomically (see the module docstring for the layout).

    ``beauty`` ``(H, W, 3)`` scene-linear, everything the camera sees (the same
    image the PNG shows).  ``alpha`` ``(H, W)`` geometry coverage in [0, 1];
    None writes RGB only.  ``background`` ``(H, W, 3)``, the sky radiance seen
    directly, averaged over the same samples as the beauty: when given, ``RGB``
    becomes ``beauty − background`` (premultiplied foreground) and the sky goes
    to ``background.RGB``, so an ``over`` onto a new sky works.  ``half_beauty``
    stores RGBA and background as half floats (data and mattes stay float32).
    ``aovs``: comp layers, name → ``(H, W, C)``, written as ``<name>.<channel>`` with the channel
    names of :data:`AOV_CHANNELS` (R, G, B for other 3-channel layers, e.g. ``lightgroup.sun``).
    ``working_space``: the colour space the caller's colour pixels are in, for the header
    (:func:`colour_space_header`; :func:`forest.imaging.working_space.from_rec709` converts them).
    """
    rgb = np.asarray(beauty, dtype=np.float32)
    if rgb.ndim != 3 or rgb.shape[2] < 3:
        raise ValueError(f"beauty must be (H, W, 3), got {rgb.shape}")
    rgb = rgb[..., :3]
    shape = rgb.shape[:2]
    channels: dict[str, np.ndarray] = {}
    bg = None
    if background is not None:
        bg = np.asarray(background, dtype=np.float32)[..., :3]
        if bg.shape[:2] != shape:
            raise ValueError(f"background is {bg.shape}, the beauty is {rgb.shape}")
        rgb = rgb - bg
    for i, c in enumerate("RGB"):
        channels[c] = rgb[..., i]
    a = _plane("alpha", alpha, shape)
    if a is not None:
        channels["A"] = np.clip(a, 0.0, 1.0)
    if bg is not None:
        for i, c in enumerate("RGB"):
            channels[f"background.{c}"] = bg[..., i]
    for name, arr in (("id.Z", tree_id), ("species.Z", species)):
        if arr is not None and np.abs(np.asarray(arr, dtype=np.float64)).max(initial=0.0) > FLOAT32_EXACT:
            raise ValueError(f"{name}: ids above {FLOAT32_EXACT} do not survive a float32 channel")
    for name, arr in (("depth.Z", depth), ("id.Z", tree_id), ("species.Z", species)):
        p = _plane(name, arr, shape)
        if p is not None:
            channels[name] = p
    for layer, arr in (aovs or {}).items():
        a3 = np.asarray(arr, dtype=np.float32)
        names = AOV_CHANNELS.get(layer, ("R", "G", "B"))
        if a3.shape != (*shape, len(names)):
            raise ValueError(f"{layer} is {a3.shape}, the layer needs {(*shape, len(names))}")
        for i, c in enumerate(names):
            if f"{layer}.{c}" in channels:
                raise ValueError(f"two layers write channel {layer}.{c}")
            channels[f"{layer}.{c}"] = a3[..., i]
    header: dict[str, object] = dict(colour_space_header(working_space))
    for m in mattes:
        for name, plane in m.channels.items():
            if name in channels:
                raise ValueError(f"two layers write channel {name}")
            channels[name] = _plane(name, plane, shape)  # type: ignore[assignment]
        header.update(m.attributes)
    if camera is not None:
        header.update(camera.header())
    if species_names:
        header["forest:species_names"] = json.dumps(list(species_names), ensure_ascii=False)
    header["forest:layers"] = _describe(
        channels, background is not None, [m.type_name for m in mattes], list(aovs or {})
    )
    header.update(attributes or {})
    half = {c for c in channels if c in ("R", "G", "B", "A") or c.startswith("background.")} if half_beauty else set()
    # zlib level 1: Cryptomatte IDs are high-entropy floats that the default level compresses no
    # better (+0.3 % bytes) at 1.5× the time (measured at 1920×1080 by bench/bench_imaging.py).
    return write_exr_channels(path, channels, attributes=header, half=half, compression="zip:1")


def _describe(
    channels: Mapping[str, np.ndarray], split_background: bool, mattes: Sequence[str], aovs: Sequence[str] = ()
) -> str:
    parts = [
        "RGB foreground (scene-linear Rec.709, premultiplied; RGB + background = beauty)"
        if split_background
        else "RGB beauty (scene-linear Rec.709, sky included)"
    ]
    if "A" in channels:
        parts.append("A coverage of geometry (0 = sky)")
    if split_background:
        parts.append("background.RGB the sky seen directly")
    if "depth.Z" in channels:
        parts.append("depth.Z distance to the first hit in metres")
    if "id.Z" in channels:
        parts.append("id.Z tree id (-1 none)")
    if "species.Z" in channels:
        parts.append("species.Z index into forest:species_names (-1 none)")
    parts += [f"{m}00.. Cryptomatte" for m in mattes]
    what = {
        "N": "N.XYZ first-hit shading normal (world, unit)",
        "P": "P.XYZ world position of the pixel-centre hit (m, 0 = none)",
        "albedo": "albedo.RGB first-hit albedo",
        "forward": "forward.uv motion vectors over one frame (pixels, u right, v up)",
    }
    parts += [what.get(a, f"{a}.RGB light from this group (groups sum to the beauty)") for a in aovs]
    return "; ".join(parts)
