"""Plain-data inputs of the forest path tracer: what to render, decoupled from any config file.

A caller (the scene hub, look-dev, a test) fills a :class:`PathInputs` from
whatever it reads; nothing here knows about TOML.  Conventions are the
product's (see ``forest.render.scene``): metres, Y up, maps laid over the
terrain's X/Z extent (column j → +X, row i → +Z, row 0 at ``zmin``), linear
RGB, the camera looking along +Z of its frame with +X to the left and a
*horizontal* field of view.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ...errors import ForestError
from .haze import HazeInputs

#: Angular diameter of the sun seen from the earth, degrees (0.5332° at 1 AU).
SUN_ANGULAR_DIAMETER = 0.53
SAMPLERS = ("multijitter", "independent", "stratified", "orthogonal", "ldsampler")
SKY_KINDS = ("constant", "envmap", "sunsky", "gradient")
#: Prototypes with at most this many triangles are merged per species into world-space
#: meshes instead of instanced (≤ 64 triangles ≈ 2.3 KB of vertices per tree, against
#: 13–17 KB per Mitsuba instance record in llvm).
FLATTEN_MAX_TRIANGLES = 64


class SeaMap(NamedTuple):
    """Still water past the terrain's edge (:mod:`forest.skirt`, "The sea"): on the skirt, outside the terrain's
    own ``extent`` (xmin, zmin, xmax, zmax), ground at height y is water of coverage
    W = 1 − s((y − ``level``)/``SHORE_RAMP``), s the smoothstep (:meth:`forest.terrain.Terrain.water_cover`'s
    rule), of albedo ``colour`` (the painted water's, :func:`forest.ground.water_colour`)."""

    level: float
    colour: tuple[float, float, float]
    extent: tuple[float, float, float, float]


@dataclass(frozen=True)
class PathCamera:
    """A camera: ``to_world`` camera→world 4×4 (looks along +Z, +Y up, +X left), horizontal ``fov``.

    A pinhole, or with ``lens_radius`` r > 0 (metres) a thin lens focused at ``focus_distance`` metres
    along the view axis (:func:`~forest.render.path.lens.thin_lens_rays`).
    """

    to_world: np.ndarray
    fov: float
    width: int
    height: int
    near: float = 0.5
    far: float = 100_000.0
    lens_radius: float = 0.0
    focus_distance: float = 1.0


@dataclass(frozen=True)
class SunLight:
    """A sun of finite angular size: soft shadows.

    ``direction`` points *towards* the sun (world, Y up); ``irradiance`` is the
    RGB irradiance (W/m²) on a plane facing the sun; ``angular_diameter`` in
    degrees.  Its radiance is uniform over the disc, L = E / (π sin²α) with α
    the angular radius, so that ∫_disc L cos θ dω = E exactly.
    """

    direction: Sequence[float]
    irradiance: Sequence[float]
    angular_diameter: float = SUN_ANGULAR_DIAMETER


@dataclass(frozen=True)
class SkyLight:
    """The sky dome.

    * ``constant`` — ``radiance`` (RGB) in every direction;
    * ``envmap`` — a latitude–longitude image (``envmap``; +Y up), times ``scale``; with
      ``background = "sunsky"`` camera rays that leave the scene see Mitsuba's sky model for
      :attr:`PathInputs.sun` instead, scaled to the map's mean radiance (the map still lights);
    * ``sunsky`` — Mitsuba's Hosek–Wilkie sky and its sun (``turbidity``, ``albedo``),
      the sky times ``scale`` and its sun times ``sun_scale``, pointed at
      :attr:`PathInputs.sun`'s direction.  Mitsuba's model is Z-up; the renderer
      rotates it to Y-up.  It replaces the disc sun (whose irradiance is then unused).
      With ``sun_irradiance`` set, sun and sky are first scaled together so that
      the model's sun sends that irradiance (luminance, facing the sun; see
      :func:`~forest.render.path.emitters.sunsky_scale`).
    * ``gradient`` — L(ω) = ``zenith``·(1 − b) + ``horizon``·b with b = (1 − μ)^k,
      μ = max(ω_y, 0) and k = ``horizon_exponent`` ≥ 1 (below the horizon, the horizon's
      radiance).  With k = 1 it is linear in the cosine of the zenith angle, and with
      zenith = 3 × horizon the CIE standard overcast sky, L(θ) ∝ (1 + 2 cos θ)/3 (Moon &
      Spencer 1942; CIE S 011/E:2003, sky type 1); a horizon brighter than the zenith
      gives the clear-sky brightening towards the horizon.  A larger k narrows the
      horizon's colour to a band about 1/k high in μ: the glow of a low sun along the
      horizon under a differently coloured sky.  Both colours are parameters
      (``sky_zenith``, ``sky_horizon``).
    """

    kind: str = "constant"
    radiance: Sequence[float] = (0.35, 0.35, 0.35)
    envmap: Path | None = None
    scale: float = 1.0
    turbidity: float = 3.0
    albedo: float = 0.15
    sun_scale: float = 1.0
    sun_irradiance: float | None = None
    background: str = "map"
    zenith: Sequence[float] = (0.35, 0.35, 0.35)
    horizon: Sequence[float] = (0.35, 0.35, 0.35)
    horizon_exponent: float = 1.0
    #: A cloud layer over this sky (:class:`forest.lights.Clouds`; see :mod:`.clouds`), or None.
    clouds: Any = None


@dataclass(frozen=True)
class Material:
    """A surface material with the fields of a library ``Part``.

    ``kind`` ``"leaf"`` (diffuse reflection R = (1 − τ)·a and transmission
    T = τ·a) or anything else (two-sided Lambertian, albedo a); a = ``colour`` ×
    texture RGB (a linear detail factor) × the colour grid where ``tinted``;
    ``texture``'s alpha cuts the surface out.  ``texture`` is an image path or
    an (h, w, 3|4) array.
    """

    kind: str
    colour: Sequence[float]
    texture: Path | np.ndarray | None = None
    tinted: bool = False
    translucency: float = 0.0
    sheen: float = 0.0  # leaves: weight of the cuticle's rough specular lobe (see .materials)
    roughness: float = 0.0  # its GGX α


@dataclass(frozen=True)
class Surface:
    """Any other world-space mesh (a ground plane, a prop): ``mesh`` is a ``MeshData``."""

    mesh: Any
    material: Material


@dataclass
class PathInputs:
    """Everything the forest path tracer needs for one frame.

    ``instances`` is the :class:`~forest.instances.InstanceSet`; ``species[s]``
    the library species (or a list of individuals, picked per tree by
    ``individuals``) of species index s; ``levels`` the level of detail of each
    tree (0 high … last = far); ``matrices`` (N, 4, 4) object→world at the
    rendered instant (wind applied).  ``colour_grid`` (H, W, 3, linear) is
    the tint looked up at each hit's world X/Z over ``extent`` (default the
    terrain's); ``terrain_colour`` is an RGB triple or an (H, W, 3) map over
    ``terrain_extent`` (default: the grid's extent), multiplied by the grid
    where ``terrain_tinted`` and by ``terrain_detail`` (a tileable RGB texture
    of mean 1, an array or an image path) repeated every
    ``terrain_detail_tile`` metres of world X/Z.  ``skirt_radius`` > 0 carries
    the terrain to the horizon (:func:`forest.skirt.skirt_mesh`), with ``skirt_hills``
    (:class:`forest.skirt.Hills`, None for a level plain) on it;
    ``haze`` is the aerial perspective (:mod:`.haze`), None for none.  Russian
    roulette starts at path vertex ``rr_depth`` (0 = the first surface): on
    the demo forest 1 gave the noise of 2 in 64 % of the time, 0 another 44 %
    less time for 16 % more noise.  Prototypes
    of at most ``flatten_triangles`` triangles are merged into world-space
    meshes instead of instanced (see :mod:`.geometry`); the trees set in ``solid``
    (N,) bool (None: none) draw their cut-out leaf cards as opaque cards of the same
    coverage (:mod:`.solid`).  ``leaf_tint`` (S, 3)
    multiplies the albedo of the leaf parts of each species index (default ones)
    and ``ground_tint`` (RGB) the terrain's; both start the ``leaf_tint`` and
    ``ground_tint`` parameters of :class:`~forest.render.path.PathScene`.
    ``terrain_water`` (H, W) in [0, 1], on the texels of an (H, W, 3) ``terrain_colour``,
    is the water coverage W of :mod:`forest.ground`: that share of the terrain is a
    Fresnel mirror (tilted by ripples of ``water_ripple`` degrees RMS) over the map's colour
    (:func:`~forest.render.path.materials.water_lobe`); None for no water.
    ``tree_tint`` (N, 3) multiplies the tinted parts of each tree besides the colour
    grid: its colour beyond the map (:meth:`forest.scene.Scene.tree_jitter`), None for 1.
    ``bark_tint`` (N, 3) multiplies each tree's ``bark`` parts (:meth:`forest.scene.Scene.bark_tints`),
    None for 1.
    ``far_cover`` (:class:`forest.far_cover.FarCover`) draws woods and open ground on the skirt past an
    (H, W, 3) ``terrain_colour``'s terrain; None keeps it one colour.
    ``sea_colour`` (RGB): with a skirt and a ``terrain`` whose still water reaches its edge, the skirt's water
    past that edge is drawn as water of this albedo (:class:`~forest.render.path.inputs.SeaMap`); None for no
    sea (the skirt's colour is then the map's, faded).
    """

    instances: Any
    species: Sequence[Any]
    levels: np.ndarray
    matrices: np.ndarray
    camera: PathCamera
    terrain: Any = None
    sun: SunLight | None = None
    sky: SkyLight | None = field(default_factory=SkyLight)
    colour_grid: np.ndarray | None = None
    extent: tuple[float, float, float, float] | None = None
    terrain_colour: Any = (0.18, 0.16, 0.11)
    terrain_tinted: bool = True
    terrain_extent: tuple[float, float, float, float] | None = None
    terrain_detail: Any = None
    terrain_detail_tile: float = 1.0
    skirt_radius: float = 0.0
    skirt_hills: Any = None
    haze: HazeInputs | None = None
    surfaces: Sequence[Surface] = ()
    individuals: np.ndarray | None = None
    max_depth: int = 4
    rr_depth: int = 1
    spp: int = 16
    seed: int = 0
    sampler: str = "multijitter"
    flatten_triangles: int = FLATTEN_MAX_TRIANGLES
    solid: np.ndarray | None = None
    #: The ``[lod]`` setting that decides how many trees are instanced (named when they do not fit in memory):
    #: ``distances`` (manual), ``pixels`` (automatic) or ``auto`` (level of detail off).
    lod_setting: str = "distances"
    leaf_tint: np.ndarray | None = None
    ground_tint: Sequence[float] = (1.0, 1.0, 1.0)
    terrain_water: np.ndarray | None = None
    water_ripple: float = 2.0
    tree_tint: np.ndarray | None = None
    far_cover: Any = None
    bark_tint: np.ndarray | None = None
    sea_colour: tuple[float, float, float] | None = None

    def sea_map(self) -> SeaMap | None:
        """The :class:`~forest.render.path.inputs.SeaMap` of ``sea_colour``, or None (no sea colour, no
        skirt, or a terrain without still water)."""
        water = getattr(self.terrain, "water", None)
        if self.sea_colour is None or water is None or self.skirt_radius <= 0.0:
            return None
        colour = tuple(float(c) for c in np.asarray(self.sea_colour, np.float64).reshape(3))
        extent = tuple(float(v) for v in self.terrain.extent)
        return SeaMap(float(water[0]), colour, extent)  # type: ignore[arg-type]

    def terrain_map_array(self) -> np.ndarray:
        """``terrain_colour`` as float32, with ``terrain_water`` as a fourth channel where there is water."""
        tc = np.asarray(self.terrain_colour, dtype=np.float32)
        if self.terrain_water is None or tc.ndim != 3:
            return tc
        w = np.asarray(self.terrain_water, np.float32)[..., None]
        return np.ascontiguousarray(np.concatenate([tc, w], axis=2))

    def tints(self) -> tuple[np.ndarray, np.ndarray]:
        """(leaf tint (S, 3), ground tint (3,)) as float64 arrays, ones where not given."""
        leaf = np.ones((len(self.species), 3)) if self.leaf_tint is None else np.asarray(self.leaf_tint, np.float64)
        return leaf.reshape(len(self.species), 3), np.asarray(self.ground_tint, np.float64).reshape(3)

    def grid_extent(self) -> tuple[float, float, float, float]:
        """(xmin, zmin, xmax, zmax) that the colour grid and a terrain colour map span."""
        if self.extent is not None:
            return tuple(float(v) for v in self.extent)  # type: ignore[return-value]
        if self.terrain is not None:
            return tuple(float(v) for v in self.terrain.extent)  # type: ignore[return-value]
        ext = getattr(self.instances, "extent", None)
        if ext is not None and float(ext[2]) > float(ext[0]) and float(ext[3]) > float(ext[1]):
            return tuple(float(v) for v in ext)  # type: ignore[return-value]
        return (-1.0, -1.0, 1.0, 1.0)

    def validate(self) -> None:
        """Raise :class:`ForestError` naming the first field that cannot be rendered."""
        n = len(self.instances)
        if np.asarray(self.levels).shape != (n,):
            raise ForestError(f"path inputs: levels must have one entry per tree ({n}), got {np.shape(self.levels)}")
        if np.asarray(self.matrices).shape != (n, 4, 4):
            raise ForestError(f"path inputs: matrices must be ({n}, 4, 4), got {np.shape(self.matrices)}")
        if n and int(np.max(self.instances.species)) >= len(self.species):
            raise ForestError("path inputs: a tree's species index has no entry in species")
        if self.individuals is not None and np.asarray(self.individuals).shape != (n,):
            raise ForestError("path inputs: individuals must have one entry per tree")
        cam = self.camera
        if not (0.0 < float(cam.fov) < 180.0):
            raise ForestError(f"path inputs: camera fov must be in (0, 180) degrees, got {cam.fov}")
        if int(cam.width) < 1 or int(cam.height) < 1:
            raise ForestError(f"path inputs: camera size must be at least 1×1, got {cam.width}×{cam.height}")
        if int(self.max_depth) < 1:
            raise ForestError(f"path inputs: max_depth must be ≥ 1, got {self.max_depth}")
        if int(self.spp) < 1:
            raise ForestError(f"path inputs: spp must be ≥ 1, got {self.spp}")
        if self.sampler not in SAMPLERS:
            raise ForestError(f"path inputs: sampler must be one of {', '.join(SAMPLERS)}, got {self.sampler!r}")
        if self.colour_grid is not None:
            g = np.asarray(self.colour_grid)
            if g.ndim != 3 or g.shape[2] != 3 or min(g.shape[:2]) < 1 or not np.isfinite(g).all():
                raise ForestError(f"path inputs: colour_grid must be a finite (H, W, 3) array, got shape {g.shape}")
        if self.leaf_tint is not None and np.shape(self.leaf_tint) != (len(self.species), 3):
            raise ForestError(
                f"path inputs: leaf_tint must be ({len(self.species)}, 3), one RGB per species, "
                f"got {np.shape(self.leaf_tint)}"
            )
        for name in ("tree_tint", "bark_tint"):
            tt = getattr(self, name)
            if tt is None:
                continue
            tt = np.asarray(tt)
            if tt.shape != (len(self.instances), 3) or not np.all(np.isfinite(tt)) or np.any(tt < 0):
                raise ForestError(
                    f"path inputs: {name} must be finite, non-negative and ({len(self.instances)}, 3), "
                    f"one RGB per tree, got shape {tt.shape}"
                )
        leaf, ground = self.tints()
        if not (np.isfinite(leaf).all() and np.isfinite(ground).all()) or leaf.min() < 0 or ground.min() < 0:
            raise ForestError("path inputs: leaf_tint and ground_tint must be finite and non-negative")
        tc = np.asarray(self.terrain_colour, dtype=np.float64)
        if tc.shape != (3,) and (tc.ndim != 3 or tc.shape[2] != 3):
            raise ForestError(f"path inputs: terrain_colour must be RGB or an (H, W, 3) map, got shape {tc.shape}")
        sky = self.sky
        if sky is not None:
            if sky.kind not in SKY_KINDS:
                raise ForestError(f"path inputs: sky kind must be one of {', '.join(SKY_KINDS)}, got {sky.kind!r}")
            if sky.kind == "envmap" and (sky.envmap is None or not Path(sky.envmap).is_file()):
                raise ForestError(f"path inputs: sky envmap {sky.envmap}: no such file")
            if sky.kind == "sunsky" and self.sun is None:
                raise ForestError("path inputs: a sunsky sky needs a sun (its direction)")
            if not (1.0 <= float(sky.horizon_exponent) <= 1000.0):
                raise ForestError(f"path inputs: sky horizon_exponent must be in [1, 1000], got {sky.horizon_exponent}")
        if self.sun is not None:
            d = np.asarray(self.sun.direction, dtype=np.float64)
            if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) == 0:
                raise ForestError(f"path inputs: sun direction must be a non-zero 3-vector, got {self.sun.direction}")
            if not (0.0 < float(self.sun.angular_diameter) < 90.0):
                raise ForestError(
                    f"path inputs: sun angular_diameter must be in (0, 90) degrees, got {self.sun.angular_diameter}"
                )
        if self.sun is None and self.sky is None:
            raise ForestError("path inputs: no light (neither sun nor sky)")
        if self.haze is not None:
            self.haze.validate()
        if self.terrain_water is not None:
            w = np.asarray(self.terrain_water, dtype=np.float64)
            if tc.ndim != 3 or w.shape != tc.shape[:2] or not np.isfinite(w).all() or w.min() < 0 or w.max() > 1:
                raise ForestError(
                    f"path inputs: terrain_water must be an (H, W) array in [0, 1] on terrain_colour's texels "
                    f"{tc.shape[:2] if tc.ndim == 3 else '(no map)'}, got shape {w.shape}"
                )
            if not (0.0 <= float(self.water_ripple) <= 20.0):
                raise ForestError(f"path inputs: water_ripple must be in [0, 20] degrees, got {self.water_ripple}")
        if self.terrain_detail is not None and not float(self.terrain_detail_tile) > 0.0:
            raise ForestError(f"path inputs: terrain_detail_tile must be > 0 m, got {self.terrain_detail_tile}")
