"""HDRI skies: the shipped latitude–longitude maps, and the sun found in a map, taken out and handed to the disc sun.

**Shipped skies.**  ``[lights.sky] hdri = "sunrise"`` names a map of ``library/skies/`` (installed as
``forest.library_files/skies``; :data:`SKIES`, :func:`sky_path`); ``library/skies/README.md`` gives each
one's source and licence.

**Pixels and directions.**  An H×W latitude–longitude map (+Y up, Mitsuba's ``envmap`` layout) has
pixel (i, j) centred on the polar angle θ = π(i + ½)/H and the longitude φ = 2π(j + ½)/W, i.e. the
direction

    d = (sin θ sin φ,  cos θ,  −sin θ cos φ)                                    (1)

(Mitsuba's ``envmap``: u = atan2(d_x, −d_z)/2π, v = acos(d_y)/π; it lays row centres at πi/(H − 1),
within half a pixel of these).  In :mod:`forest.lights`' convention the elevation is E = asin d_y and
the azimuth A = atan2(d_x, d_z) = 180° − φ.  The pixel's solid angle is exactly

    Ω_i = (2π/W) · (cos θ_i⁻ − cos θ_i⁺),   θ_i^∓ = π i/H, π(i + 1)/H            (2)

(≈ (2π/W)(π/H) cos(latitude)).

**Finding the sun** (:func:`find_sun`).  With Y the Rec. 709 luminance of each pixel and q the
Ω-weighted :data:`SKY_QUANTILE` quantile of Y over the sphere (the sky's top level), the sun is the
8-connected region of pixels brighter than τ = :data:`SUN_CONTRAST` · q that holds the brightest pixel
(longitude wraps round), grown by :data:`SUN_MARGIN` pixels to take its glare and any compression
ringing; a map whose brightest pixel is not above τ, whose region spans more than
:data:`MAX_SUN_SOLID_ANGLE`, or whose region lies below the horizon has no sun.

**Taking it out.**  The region is refilled with the surrounding sky's level: the harmonic
interpolation F of the pixels around it (∇²F = 0 inside, F = the map on its rim; a sparse solve), so
the fill is smooth and never brighter than its rim.  The light taken out is the sun, per RGB channel

    E = Σ_region (L − F) Ω                                                       (3)

— the irradiance it sends facing it (its half-degree width makes the cosine 1 to 10⁻⁴), and exactly
what the map lost, so the scene's energy is kept.  Its direction is the centroid of (1) weighted by
w = max(Y(L − F), 0) Ω (luminance-weighted, solid-angle-weighted): s = Σ w d / |Σ w d|.  The
:class:`~forest.lights.Sun` has irradiance Y(E) and colour E / Y(E).

**Cache.**  The processed map is written once to ``$FOREST_CACHE_DIR/skies/`` (else the user cache
folder), named by the SHA-256 of the source's bytes and :data:`VERSION`, as a half-float EXR whose
header carries the sun found; the same map gives a byte-identical file, and :func:`split_sun` memoises
it by path, size and modification time within a process.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import ForestError

#: The shipped skies, by name: ``library/skies/<name>.exr``.
SKIES = ("sunrise", "sunset")
#: Ω-weighted quantile of the map's luminance taken as the sky's top level q.
SKY_QUANTILE = 0.99
#: A pixel is the sun's when brighter than this many times q.
SUN_CONTRAST = 10.0
#: Pixels added around the sun's region (its glare, the ringing of lossy compression) before the refill.
SUN_MARGIN = 2
#: Largest solid angle (sr) of a sun's region; a brighter area larger than this (about 4.6° across) is not a sun.
MAX_SUN_SOLID_ANGLE = 0.02
#: Largest value of a half-float EXR: the processed map is clamped to it.
HALF_MAX = 65504.0
#: Changes with the algorithm, so that an older cache file is not reused.
VERSION = "hdri-sun-1"
#: Rec. 709 luminance weights.
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
#: Header attributes of a processed map that carry its sun.
_ATTRS = ("forest:sun_elevation", "forest:sun_azimuth", "forest:sun_irradiance", "forest:sun_colour")


def sky_path(name: str) -> Path:
    """The shipped map ``name`` (one of :data:`SKIES`), from the checkout or an installed wheel."""
    if name not in SKIES:
        raise ForestError(f"unknown sky {name!r}; the shipped skies are {', '.join(SKIES)}")
    from importlib.resources import files

    return Path(str(files("forest.library_files"))) / "skies" / f"{name}.exr"


@dataclass(frozen=True)
class MapSun:
    """The sun found in a map: elevation and azimuth (degrees, :mod:`forest.lights`' convention), irradiance
    facing it per RGB channel (map units × sr), and its region (a boolean H×W mask, the refilled pixels)."""

    elevation: float
    azimuth: float
    rgb: tuple[float, float, float]
    region: np.ndarray

    @property
    def irradiance(self) -> float:
        """Luminance of :attr:`rgb`, Y(E)."""
        return float(LUMINANCE @ np.asarray(self.rgb))

    @property
    def colour(self) -> tuple[float, float, float]:
        """:attr:`rgb` over its luminance (luminance 1)."""
        y = self.irradiance
        r, g, b = (float(c) / y if y > 0 else 1.0 for c in self.rgb)
        return (r, g, b)


def solid_angles(height: int, width: int) -> np.ndarray:
    """(H, 1) solid angle of each row's pixels, equation (2)."""
    edges = np.cos(np.pi * np.arange(height + 1) / height)
    return ((2.0 * np.pi / width) * (edges[:-1] - edges[1:]))[:, None]


def directions(height: int, width: int) -> np.ndarray:
    """(H, W, 3) unit direction of each pixel's centre, equation (1)."""
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    return np.stack([st * np.sin(phi), np.broadcast_to(ct, (height, width)), -st * np.cos(phi)], axis=-1)


def weighted_quantile(values: np.ndarray, weights: np.ndarray, q: float) -> float:
    """The q-quantile of ``values`` where each counts by its ``weights`` (same shape)."""
    v, w = values.ravel(), np.broadcast_to(weights, values.shape).ravel()
    order = np.argsort(v, kind="stable")
    c = np.cumsum(w[order])
    k = int(np.searchsorted(c, q * c[-1]))
    return float(v[order][min(k, v.size - 1)])


def _harmonic_fill(img: np.ndarray, region: np.ndarray) -> np.ndarray:
    """``img`` with the pixels of ``region`` replaced by the harmonic interpolation of their rim.

    ∇²F = 0 on the 4-neighbour grid inside the region, F = ``img`` outside; longitude wraps round, the
    poles' rows have no neighbour beyond them.  One sparse solve per channel (scipy).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import splu

    h, w = region.shape
    ii, jj = np.nonzero(region)
    index = -np.ones((h, w), dtype=np.int64)
    index[ii, jj] = np.arange(ii.size)
    rows, cols, vals = [], [], []
    rhs = np.zeros((ii.size, img.shape[2]))
    degree = np.zeros(ii.size)
    for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        ni, nj = ii + di, (jj + dj) % w
        ok = (ni >= 0) & (ni < h)
        degree += ok
        k = np.nonzero(ok)[0]
        inside = index[ni[k], nj[k]]
        unknown = inside >= 0
        rows.append(k[unknown])
        cols.append(inside[unknown])
        vals.append(-np.ones(int(unknown.sum())))
        known = k[~unknown]
        rhs[known] += img[ni[known], nj[known]]
    rows.append(np.arange(ii.size))
    cols.append(np.arange(ii.size))
    vals.append(degree)
    a = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(ii.size,) * 2)
    solved = splu(a.tocsc()).solve(rhs)
    out = img.copy()
    out[ii, jj] = solved
    return out


def find_sun(rgb: np.ndarray) -> tuple[MapSun | None, np.ndarray]:
    """The sun of lat-long map ``rgb`` (H, W, 3) and the map with it taken out (float64); (None, the map)
    when it has none.  The maths is the module docstring's."""
    from scipy import ndimage

    img = np.asarray(rgb, dtype=np.float64)[..., :3]
    h, w = img.shape[:2]
    omega = solid_angles(h, w)
    y = img @ LUMINANCE
    q = weighted_quantile(y, omega, SKY_QUANTILE)
    peak = np.unravel_index(int(np.argmax(y)), y.shape)
    tau = SUN_CONTRAST * max(q, 0.0)
    if not y[peak] > tau:
        return None, img
    # Roll the peak to the middle column so that labelling needs no wrap (a sun is far narrower than the map).
    shift = w // 2 - int(peak[1])
    labels, _ = ndimage.label(np.roll(y > tau, shift, axis=1), structure=np.ones((3, 3), bool))
    core = np.roll(labels == labels[peak[0], w // 2], -shift, axis=1)
    if float((core * omega).sum()) > MAX_SUN_SOLID_ANGLE:
        return None, img
    region = np.roll(
        ndimage.binary_dilation(np.roll(core, shift, axis=1), np.ones((3, 3), bool), iterations=SUN_MARGIN),
        -shift,
        axis=1,
    )
    filled = _harmonic_fill(img, region)
    taken = (img - filled) * omega[..., None] * region[..., None]
    weight = np.maximum(taken @ LUMINANCE, 0.0)
    s = (weight[..., None] * directions(h, w)).sum(axis=(0, 1))
    s /= np.linalg.norm(s)
    elevation = math.degrees(math.asin(float(np.clip(s[1], -1.0, 1.0))))
    if elevation <= 0.0:
        return None, img
    azimuth = math.degrees(math.atan2(float(s[0]), float(s[2]))) % 360.0
    e = np.maximum(taken.sum(axis=(0, 1)), 0.0)
    sun = MapSun(elevation, azimuth, (float(e[0]), float(e[1]), float(e[2])), region)
    return sun, filled


def cache_folder() -> Path:
    """Where processed maps go: ``$FOREST_CACHE_DIR/skies``, else ``skies`` in the user cache folder."""
    from .cache import cache_folder as folder

    return folder("skies")


@dataclass(frozen=True)
class SplitMap:
    """A map with its sun taken out: the processed file, the source, and the sun (None: the map had none,
    and ``path`` is the source itself)."""

    path: Path
    source: Path
    elevation: float | None = None
    azimuth: float | None = None
    irradiance: float = 0.0
    colour: tuple[float, float, float] = (1.0, 1.0, 1.0)


_memo: dict[tuple[str, int, int, str, float, bool], SplitMap] = {}


def _read_header(path: Path) -> dict[str, object]:
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()
        return {}
    spec = inp.spec()
    inp.close()
    return {name: spec.getattribute(name) for name in _ATTRS if spec.getattribute(name) is not None}


def _from_header(path: Path, source: Path, attrs: dict[str, object]) -> SplitMap | None:
    try:
        colour = tuple(float(c) for c in attrs["forest:sun_colour"])  # type: ignore[attr-defined]
        return SplitMap(
            path,
            source,
            float(attrs["forest:sun_elevation"]),  # type: ignore[arg-type]
            float(attrs["forest:sun_azimuth"]),  # type: ignore[arg-type]
            float(attrs["forest:sun_irradiance"]),  # type: ignore[arg-type]
            (colour[0], colour[1], colour[2]),
        )
    except (KeyError, TypeError, ValueError, IndexError):
        return None


def rotate(rgb: np.ndarray, degrees: float) -> np.ndarray:
    """The lat-long map turned about +Y by ``degrees``: every azimuth in it grows by that much.

    A column's azimuth is 180° − φ (φ its longitude, equation (1), azimuth = atan2(d_x, d_z)), so the
    turned map at column j is the map at φ_j + Δ, Δ = ``degrees``: a cyclic shift of s = Δ·W/360
    columns, linear between the two whole shifts around it (energy and rows kept)."""
    img = np.asarray(rgb)
    shift = (float(degrees) % 360.0) * img.shape[1] / 360.0
    k = int(math.floor(shift))
    f = shift - k
    out = np.roll(img, -k, axis=1)
    if f > 0.0:
        out = (1.0 - f) * out + f * np.roll(img, -k - 1, axis=1)
    return np.asarray(out, img.dtype)


def split_sun(source: str | Path, *, rotation: float = 0.0, take_sun: bool = True) -> SplitMap:
    """Map ``source`` turned by ``rotation`` degrees (:func:`rotate`) with its sun taken out (:func:`find_sun`;
    kept with ``take_sun`` false), written to the cache once and memoised.

    A map left as it was (no turn, no sun) comes back as itself (``path == source``, no sun).  Unreadable
    maps raise :class:`ForestError` (:func:`forest.images.read_image`).
    """
    from .images import read_image, write_image

    source = Path(source)
    st = source.stat()
    folder = cache_folder()
    rotation = float(rotation) % 360.0
    key = (str(source.resolve()), st.st_size, st.st_mtime_ns, str(folder), rotation, bool(take_sun))
    if key in _memo and _memo[key].path.is_file():
        return _memo[key]
    salt = VERSION.encode() + (b"" if rotation == 0.0 and take_sun else repr((rotation, take_sun)).encode())
    digest = hashlib.sha256(salt + b"\0" + source.read_bytes()).hexdigest()[:24]
    out = folder / f"{source.stem}-{digest}.exr"
    result = None
    if out.is_file():
        result = _from_header(out, source, _read_header(out)) if take_sun else SplitMap(out, source)
    if result is None:
        img = read_image(source, what="environment map")
        if rotation != 0.0:
            img = rotate(img, rotation)
        sun, filled = find_sun(img) if take_sun else (None, img)
        if sun is None and rotation == 0.0:
            result = SplitMap(source, source)
        elif sun is None:
            out.parent.mkdir(parents=True, exist_ok=True)
            write_image(out, np.clip(filled, 0.0, HALF_MAX), attributes={"forest:source": source.name})
            result = SplitMap(out, source)
        else:
            attrs = {
                "forest:sun_elevation": sun.elevation,
                "forest:sun_azimuth": sun.azimuth,
                "forest:sun_irradiance": sun.irradiance,
                "forest:sun_colour": np.asarray(sun.colour, dtype=np.float32),
                "forest:source": source.name,
            }
            out.parent.mkdir(parents=True, exist_ok=True)
            write_image(out, np.clip(filled, 0.0, HALF_MAX), attributes=attrs)
            # The header holds float32: read it back so that a fresh run and a cached one agree to the bit.
            result = _from_header(out, source, _read_header(out))
            assert result is not None
    _memo[key] = result
    return result
