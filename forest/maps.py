"""Painted maps laid over the terrain's X/Z extent, sampled at tree positions.

All maps follow the convention in :mod:`forest.terrain`: column → +X, row → +Z,
row 0 at the smallest Z, each pixel a cell of the extent.

* presence  — binary: grey ≥ threshold allows trees (nearest pixel).
* density   — grey level = relative density in [0, 1] (bilinear).
* colour    — sRGB image → linear RGB, normalised to a tint of mean 1
  (:func:`colour_tint_grid`), bilinear in linear light (:func:`colour_at`).
* partition — label colours → region index, nearest pixel, matched within a
  tolerance (max per-channel difference in 8-bit sRGB units).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .config import Config, Partition
from .errors import ForestError
from .images import read_image, read_map_grey, read_map_rgb
from .parallel import rowwise


def pixel_coords(u: np.ndarray, v: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Map coordinates in [0, 1] → continuous pixel coordinates (row, col) of pixel centres."""
    h, w = shape[:2]
    return np.asarray(v) * h - 0.5, np.asarray(u) * w - 0.5


def sample_nearest(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Nearest-pixel lookup of ``img`` at map coordinates (u, v) in [0, 1] (v down the rows), clamped to the edges."""
    h, w = img.shape[:2]
    i = np.clip(np.floor(np.asarray(v) * h).astype(np.int64), 0, h - 1)
    j = np.clip(np.floor(np.asarray(u) * w).astype(np.int64), 0, w - 1)
    return img[i, j]


def sample_bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear lookup with clamp-to-edge; ``img`` (H, W) or (H, W, C).  Split over the cores for many points
    (:func:`forest.parallel.rowwise`)."""
    u, v = np.atleast_1d(np.asarray(u)), np.atleast_1d(np.asarray(v))
    return rowwise(lambda uu, vv: _bilinear(img, uu, vv), u, v)


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    h, w = img.shape[:2]
    r, c = pixel_coords(u, v, img.shape)
    r = np.clip(r, 0.0, h - 1.0)
    c = np.clip(c, 0.0, w - 1.0)
    i0 = np.minimum(r.astype(np.int64), max(h - 2, 0))
    j0 = np.minimum(c.astype(np.int64), max(w - 2, 0))
    i1 = np.minimum(i0 + 1, h - 1)
    j1 = np.minimum(j0 + 1, w - 1)
    tr = (r - i0).astype(np.float32)
    tc = (c - j0).astype(np.float32)
    if img.ndim == 3:
        tr = tr[:, None]
        tc = tc[:, None]
    top = img[i0, j0] * (1 - tc) + img[i0, j1] * tc
    bot = img[i1, j0] * (1 - tc) + img[i1, j1] * tc
    return top * (1 - tr) + bot * tr


@dataclass
class PartitionMap:
    """Partition labels per pixel: index into ``names``; ``unlabelled`` index for others."""

    labels: np.ndarray  # (H, W) int16
    names: list[str]
    unlabelled_pixels: int
    unlabelled_colours: list[tuple[int, int, int]]

    @property
    def unlabelled(self) -> int:
        """Index of the ``unlabelled`` partition in :attr:`names`, −1 when every pixel has a label."""
        return self.names.index("unlabelled") if "unlabelled" in self.names else -1


def label_partitions(img8: np.ndarray, partitions: tuple[Partition, ...], tolerance: int) -> PartitionMap:
    """Assign each pixel the nearest label colour within ``tolerance`` (Chebyshev, 8-bit)."""
    h, w = img8.shape[:2]
    flat = img8.reshape(-1, 3).astype(np.int16)
    # Work on unique colours: painted maps have few.
    colours, inverse = np.unique(flat, axis=0, return_inverse=True)
    labels_u = np.full(len(colours), -1, dtype=np.int16)
    best = np.full(len(colours), 10**6)
    for k, p in enumerate(partitions):
        d = np.abs(colours - np.array(p.colour, dtype=np.int16)).max(axis=1)
        take = (d <= tolerance) & (d < best)
        labels_u[take] = k
        best[take] = d[take]
    names = [p.name for p in partitions]
    unl = labels_u < 0
    counts = np.bincount(inverse.ravel(), minlength=len(colours))
    n_unl = int(counts[unl].sum())
    if n_unl:
        names.append("unlabelled")
        labels_u[unl] = len(names) - 1
    order = np.argsort(-counts[unl], kind="stable")
    unl_cols = [(int(c[0]), int(c[1]), int(c[2])) for c in colours[unl][order][:5]]
    return PartitionMap(labels_u[inverse.ravel()].reshape(h, w), names, n_unl, unl_cols)


class MapSet:
    """The ``[maps]`` of a config, loaded once and sampled many times; ``colour``, the colour map's tint grid
    (:func:`colour_tint_grid`) when the caller has read the map already (the Scene does), else it is read here."""

    def __init__(self, config: Config, colour: np.ndarray | None = None):
        m = config.maps
        self.config = config
        self.presence_threshold = m.presence_threshold
        self._edge_grids: dict[tuple[float, ...], np.ndarray | None] = {}  # extent → signed edge distance per pixel
        where = f"{config.path}: maps" if config.path else "maps"

        def load(fn, key, path, **kw):
            if path is None:
                return None
            try:
                return fn(path, what=f"{key} map", **kw)
            except ForestError as e:
                raise ForestError(f"{where}.{key}: {e}") from None

        self.presence = load(read_map_grey, "presence", m.presence)
        self.density = load(read_map_grey, "density", m.density)
        if colour is not None or m.colour is None:
            self.colour = colour
        else:
            raw = load(lambda p, what: read_colour_map(p), "colour", m.colour)  # noqa: ARG005 (load passes what=)
            self.colour = colour_tint_grid(raw, m.colour_normalise)[0]
        self.partition: PartitionMap | None = None
        if m.partition is not None:
            raw = load(read_image, "partition", m.partition)
            rgb = np.repeat(raw[..., :1], 3, axis=2) if raw.shape[2] < 3 else raw[..., :3]
            img8 = np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)
            parts = config.partitions
            if not parts:
                raise ForestError(
                    f"{config.path}: partitions: [maps] partition is given but no [partitions] label colours"
                )
            self.partition = label_partitions(img8, parts, config.partition_tolerance)
        if self.presence is not None and not (self.presence >= self.presence_threshold).any():
            raise ForestError(
                f"{where}.presence: {m.presence} allows no trees anywhere (all below {self.presence_threshold:g})"
            )

    @property
    def partition_names(self) -> list[str]:
        """The partition names, ``["default"]`` without a partition map."""
        return self.partition.names if self.partition is not None else ["default"]

    def present(self, u, v) -> np.ndarray:
        """Whether the presence map allows a tree at (u, v): value ≥ ``presence_threshold`` (all True without a map)."""
        if self.presence is None:
            return np.ones(len(u), dtype=bool)
        return sample_nearest(self.presence, u, v) >= self.presence_threshold

    def edge_distance(self, u, v, extent: tuple[float, float, float, float]) -> np.ndarray:
        """Signed distance, metres, from map points (u, v) to the presence map's edge (its threshold contour):
        positive where trees may grow, negative outside; +∞ everywhere without a map or without an edge.

        The thresholded map's Euclidean distance transforms (pixel sizes along X and Z from ``extent``),
        less half a pixel so that it is 0 on the edge between two pixel centres, bilinear between pixel
        centres.
        """
        signed = self._edge_grid(tuple(float(e) for e in extent))
        return np.full(len(u), np.inf) if signed is None else sample_bilinear(signed, u, v)

    def _edge_grid(self, extent: tuple[float, ...]) -> np.ndarray | None:
        """The signed distance per map pixel for :meth:`edge_distance` (None: no map or no edge), computed once
        per extent: the trees' edge taper and every ground cover's edge band read the same grid."""
        from scipy.ndimage import distance_transform_edt

        if extent in self._edge_grids:
            return self._edge_grids[extent]
        signed = None
        inside = None if self.presence is None else self.presence >= self.presence_threshold
        if inside is not None and not inside.all():
            h, w = inside.shape
            dx, dz = (extent[2] - extent[0]) / w, (extent[3] - extent[1]) / h
            half = 0.25 * (dx + dz)
            signed = np.where(
                inside,
                distance_transform_edt(inside, sampling=(dz, dx)) - half,
                -(distance_transform_edt(~inside, sampling=(dz, dx)) - half),
            )
        self._edge_grids[extent] = signed
        return signed

    def density_at(self, u, v) -> np.ndarray:
        """The density map at (u, v), bilinear and clipped to [0, 1] (1 without a map)."""
        if self.density is None:
            return np.ones(len(u), dtype=np.float32)
        return np.clip(sample_bilinear(self.density, u, v), 0.0, 1.0)

    def tint_at(self, x: np.ndarray, z: np.ndarray, extent: tuple[float, float, float, float]) -> np.ndarray:
        """The colour map's tint (mean 1) at world (x, z), bilinear: ``(N, 3)`` float32 (1 without a map)."""
        if self.colour is None:
            return np.ones((len(x), 3), dtype=np.float32)
        return colour_at(self.colour, extent, x, z)

    def partition_at(self, u, v) -> np.ndarray:
        """Partition index at (u, v), nearest pixel (0 without a partition map)."""
        if self.partition is None:
            return np.zeros(len(u), dtype=np.int16)
        return sample_nearest(self.partition.labels, u, v)


def read_colour_map(path: Path) -> np.ndarray:
    """The colour map as linear RGB ``(H, W, 3)`` float32: the one reader of ``[maps] colour``.

    sRGB-encoded images are decoded to linear light; scatter's tints, every
    renderer, the exporters and look-dev all take the map from here (through
    :class:`MapSet` or :func:`forest.scene.load_scene`).
    """
    return read_map_rgb(path, what="colour map")


#: A normalised tint is clipped to this: a map that is black but for a few bright pixels would
#: otherwise push those trees' albedo past 1 (the mean then stays just under 1).
TINT_MAX = 4.0
#: Below this mean a channel carries no tint (a map with no red at all leaves red as the species has it).
TINT_MIN_MEAN = 1e-6


def colour_tint_grid(rgb: np.ndarray, mode: str = "rgb") -> tuple[np.ndarray, np.ndarray]:
    """The colour map as a tint around each species' own colour: ``(tint (H, W, 3) float32, divisor (3,))``.

    A painted map is a *relative* colour: multiplied as painted, an 8-bit map
    (values ≤ 1, typically 0.05–0.5 in linear light) can only darken the
    calibrated leaf albedos of the library, by 3–10× for the example maps.  So
    the map m is divided by its mean over the terrain's extent (every pixel
    covers the same area of the X/Z extent, so the mean is the pixel mean),
    in linear light because reflectance multiplies linearly:

    * ``"rgb"`` (default) — per channel, t_c = m_c / ⟨m_c⟩.  The canopy's mean
      colour is then each species' measured leaf colour and the map carries the
      variation only (a greener patch, a yellow one).  A channel whose mean is
      0 (< :data:`TINT_MIN_MEAN`) stays 1.
    * ``"luminance"`` — t = m / ⟨Y(m)⟩ with Y the luminance of linear sRGB
      (Rec. 709 primaries, D65: Y = 0.2126 R + 0.7152 G + 0.0722 B): the mean
      brightness is the species' own, but the map's overall hue stays (paint a
      whole forest autumnal).
    * ``"none"`` — t = m: an absolute multiplier (what look-dev fits and writes).

    The tint is clipped to [0, :data:`TINT_MAX`].  ``divisor`` is what the map
    was divided by (per channel; 1 for ``"none"``).
    """
    m = np.asarray(rgb, dtype=np.float64)
    if mode == "none":
        divisor = np.ones(3)
    elif mode == "rgb":
        mean = m.reshape(-1, 3).mean(axis=0)
        divisor = np.where(mean < TINT_MIN_MEAN, 1.0, mean)
        m = np.where(mean < TINT_MIN_MEAN, 1.0, m)
    elif mode == "luminance":
        import colour

        weights = colour.models.RGB_COLOURSPACE_sRGB.matrix_RGB_to_XYZ[1]
        y = float((m.reshape(-1, 3) @ weights).mean())
        divisor = np.full(3, y if y >= TINT_MIN_MEAN else 1.0)
    else:
        raise ValueError(f"unknown colour normalisation {mode!r}")
    tint = np.clip(m / divisor, 0.0, TINT_MAX)
    return tint.astype(np.float32), divisor


def colour_at(tint: np.ndarray, extent: tuple[float, float, float, float], x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Bilinear lookup of a grid laid over ``extent`` (map convention) at world (x, z), clamped: ``(N, 3)`` float32.

    The one lookup of the colour map at a position: scatter's tint column and
    the Scene's colour grid both use it, so they agree bit for bit.
    """
    xmin, zmin, xmax, zmax = extent
    u = (np.asarray(x, np.float64) - xmin) / max(xmax - xmin, 1e-12)
    v = (np.asarray(z, np.float64) - zmin) / max(zmax - zmin, 1e-12)
    return np.asarray(sample_bilinear(tint, u, v), dtype=np.float32)


def terrain_moisture(height: np.ndarray, slope_deg: np.ndarray, height_range: tuple[float, float]) -> np.ndarray:
    """Soil moisture in [0, 1] where no moisture map is painted: low and flat ground is wet.

    m = (1 − ĥ)(1 − θ/90°) with ĥ = (h − h_min)/(h_max − h_min) the normalised
    height and θ the slope (the ecosystem's site moisture and the ground's
    ``moisture`` windows both read it).
    """
    hmin, hmax = height_range
    hn = (np.asarray(height, np.float64) - hmin) / max(hmax - hmin, 1e-9)
    return np.clip((1.0 - hn) * (1.0 - np.asarray(slope_deg, np.float64) / 90.0), 0.0, 1.0)
