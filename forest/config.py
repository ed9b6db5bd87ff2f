"""Scene configuration: one TOML file, validated field by field.

:func:`load_config` reads the file and returns a :class:`Config`, whose
sections are parsed and validated on first access (``config.terrain``,
``config.scatter``, ``config.camera`` …).  Every problem raises
:class:`~forest.errors.ConfigError` naming the file and the dotted field,
e.g. ``scene.toml: species[1].percent: must be between 0 and 100, got 140``.

Relative paths in a config are relative to the config file's folder.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

from .errors import ConfigError, ForestError

MAX_TREES = 20_000_000


class Fields:
    """Typed accessors over one TOML table that report errors by dotted path."""

    def __init__(self, table: Any, where: str, config: Config, known: Iterable[str] | None = None):
        self.config = config
        self.where = where
        if table is None:
            table = {}
        if not isinstance(table, dict):
            self.fail(None, f"must be a table, got {type(table).__name__}")
        self.table = table
        if known is not None:
            unknown = sorted(set(table) - set(known))
            if unknown:
                self.fail(unknown[0], f"unknown key (expected one of: {', '.join(sorted(known))})")

    # -- helpers ---------------------------------------------------------
    def path(self, key: str | None) -> str:
        if key is None:
            return self.where
        return f"{self.where}.{key}" if self.where else key

    def fail(self, key: str | None, message: str):
        raise ConfigError(self.config.path, self.path(key), message)

    def has(self, key: str) -> bool:
        return key in self.table

    def sub(self, key: str, known: Iterable[str] | None = None) -> Fields:
        return Fields(self.table.get(key), self.path(key), self.config, known)

    # -- scalars ---------------------------------------------------------
    def number(
        self,
        key: str,
        default: float | None = None,
        *,
        lo: float | None = None,
        hi: float | None = None,
        lo_open: bool = False,
        required: bool = False,
    ) -> float:
        if key not in self.table:
            if required or default is None:
                self.fail(key, "is required")
            return float(default)
        v = self.table[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(key, f"must be a number, got {v!r}")
        v = float(v)
        if not math.isfinite(v):
            self.fail(key, f"must be finite, got {v}")
        if lo is not None and (v < lo or (lo_open and v <= lo)):
            self.fail(key, f"must be {'>' if lo_open else '>='} {lo:g}, got {v:g}")
        if hi is not None and v > hi:
            self.fail(key, f"must be <= {hi:g}, got {v:g}")
        return v

    def integer(
        self,
        key: str,
        default: int | None = None,
        *,
        lo: int | None = None,
        hi: int | None = None,
        required: bool = False,
    ) -> int:
        if key not in self.table:
            if required or default is None:
                self.fail(key, "is required")
            return int(default)
        v = self.table[key]
        if isinstance(v, bool) or not isinstance(v, int):
            if isinstance(v, float) and v.is_integer():
                v = int(v)
            else:
                self.fail(key, f"must be a whole number, got {v!r}")
        if lo is not None and v < lo:
            self.fail(key, f"must be >= {lo}, got {v}")
        if hi is not None and v > hi:
            self.fail(key, f"must be <= {hi}, got {v}")
        return int(v)

    def boolean(self, key: str, default: bool) -> bool:
        v = self.table.get(key, default)
        if not isinstance(v, bool):
            self.fail(key, f"must be true or false, got {v!r}")
        return v

    def string(
        self, key: str, default: str | None = None, *, choices: Sequence[str] | None = None, required: bool = False
    ) -> str | None:
        if key not in self.table:
            if required:
                self.fail(key, "is required")
            return default
        v = self.table[key]
        if not isinstance(v, str) or not v:
            self.fail(key, f"must be a non-empty string, got {v!r}")
        if choices is not None and v not in choices:
            self.fail(key, f"must be one of {', '.join(choices)}; got {v!r}")
        return v

    def vector(
        self,
        key: str,
        n: int,
        default: Sequence[float] | None = None,
        *,
        lo: float | None = None,
        hi: float | None = None,
        required: bool = False,
    ) -> tuple[float, ...]:
        if key not in self.table:
            if required or default is None:
                self.fail(key, "is required")
            return tuple(float(x) for x in default)
        v = self.table[key]
        if (
            not isinstance(v, list)
            or len(v) != n
            or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in v)
        ):
            self.fail(key, f"must be a list of {n} numbers, got {v!r}")
        out = tuple(float(x) for x in v)
        if any(not math.isfinite(x) for x in out):
            self.fail(key, f"must be finite, got {v!r}")
        if lo is not None and any(x < lo for x in out):
            self.fail(key, f"values must be >= {lo:g}, got {v!r}")
        if hi is not None and any(x > hi for x in out):
            self.fail(key, f"values must be <= {hi:g}, got {v!r}")
        return out

    def range(
        self, key: str, default: Sequence[float] | None, *, lo: float | None = None, hi: float | None = None
    ) -> tuple[float, float] | None:
        if key not in self.table and default is None:
            return None
        a, b = self.vector(key, 2, default, lo=lo, hi=hi)
        if a > b:
            self.fail(key, f"first value must not exceed the second, got [{a:g}, {b:g}]")
        return a, b

    def colour(self, key: str, default: Sequence[float] | None = None) -> tuple[float, float, float]:
        return self.vector(key, 3, default, lo=0.0)

    def file(self, key: str, required: bool = False, *, must_exist: bool = True) -> Path | None:
        """A path relative to the config's folder; must exist unless told otherwise."""
        s = self.string(key, required=required)
        if s is None:
            return None
        p = Path(s).expanduser()
        if not p.is_absolute():
            p = self.config.base_dir / p
        if must_exist and not p.is_file():
            self.fail(key, f"file not found: {s}")
        return p


# ---------------------------------------------------------------------------
# Sections
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class TerrainConfig:
    kind: str  # "heightmap" | "mesh" | "procedural" | "flat"
    heightmap: Path | None = None
    mesh: Path | None = None
    size: tuple[float, float] = (1000.0, 1000.0)
    height: float = 100.0
    octaves: int = 6
    resolution: int = 512
    roughness: float = 0.5
    seed: int = 0


@dataclass(frozen=True)
class MapsConfig:
    presence: Path | None = None
    density: Path | None = None
    colour: Path | None = None
    partition: Path | None = None
    presence_threshold: float = 0.5
    moisture: Path | None = None


@dataclass(frozen=True)
class ScatterConfig:
    count: int = 10000
    min_distance: float = 0.0
    align_to_normal: float = 0.0  # 0 = upright, 1 = fully along the terrain normal
    method: str = "random"


@dataclass(frozen=True)
class SpeciesConfig:
    model: str
    percent: float
    scale: tuple[float, float] = (1.0, 1.0)
    slope_max: float = 90.0
    slope_min: float = 0.0
    altitude: tuple[float, float] | None = None
    align: float | None = None  # overrides scatter.align_to_normal for this species
    yaw_step: float = 0.0  # degrees; > 0 snaps yaw to multiples (street-aligned buildings)
    partitions: tuple[str, ...] | None = None  # regions this species may grow in (None = all)
    extra: dict = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class Partition:
    colour: tuple[int, int, int]  # 8-bit sRGB label colour
    name: str


@dataclass(frozen=True)
class CameraKey:
    frame: float
    position: tuple[float, float, float]
    target: tuple[float, float, float]
    fov: float


@dataclass(frozen=True)
class CameraConfig:
    position: tuple[float, float, float]
    target: tuple[float, float, float]
    fov: float = 40.0
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    keys: tuple[CameraKey, ...] = ()
    shutter: float = 0.0  # fraction of a frame; > 0 = motion blur
    near: float = 0.5
    far: float = 100000.0
    fps: float = 24.0


@dataclass(frozen=True)
class SunConfig:
    elevation: float = 35.0  # degrees above the horizon
    azimuth: float = 120.0  # degrees, clockwise from +Z (north) towards +X (east)
    irradiance: float = 3.0
    colour: tuple[float, float, float] = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class SkyConfig:
    kind: str = "constant"  # "constant" | "envmap" | "sunsky"
    radiance: float = 0.35
    colour: tuple[float, float, float] = (1.0, 1.0, 1.0)
    envmap: Path | None = None
    scale: float = 1.0
    turbidity: float = 3.0
    albedo: float = 0.15


@dataclass(frozen=True)
class LightsConfig:
    sun: SunConfig | None
    sky: SkyConfig | None


@dataclass(frozen=True)
class RenderConfig:
    width: int = 1280
    height: int = 720
    spp: int = 64
    variant: str | None = None
    max_depth: int = 6
    subframes: int = 5  # sub-frames averaged for motion blur
    haze: float = 0.0  # aerial perspective: extinction per metre
    haze_colour: tuple[float, float, float] | None = None
    terrain_colour: tuple[float, float, float] = (0.18, 0.16, 0.11)
    seed: int = 0
    terrain_texture: Path | None = None  # image over the extent (map convention); overrides terrain_colour
    alpha_shadows: bool = False  # shadow rays see through leaf-card alpha (volpath; slower)


@dataclass(frozen=True)
class LodConfig:
    distances: tuple[float, ...] = ()  # high → medium → low → far boundaries (metres)
    enabled: bool = False


@dataclass(frozen=True)
class WindConfig:
    strength: float = 0.0  # sway amplitude in degrees
    frequency: float = 0.4  # sways per second
    direction: float = 0.0  # degrees (same convention as sun azimuth)


def _parse_colour_label(s: str, fields: Fields) -> tuple[int, int, int]:
    t = s.strip().lstrip("#")
    if len(t) == 3:
        t = "".join(c * 2 for c in t)
    try:
        if len(t) != 6:
            raise ValueError
        return int(t[0:2], 16), int(t[2:4], 16), int(t[4:6], 16)
    except ValueError:
        fields.fail(s, 'partition keys must be colours like "#ff0000"')


TOP_LEVEL_KEYS = (
    "seed",
    "name",
    "terrain",
    "maps",
    "partitions",
    "scatter",
    "species",
    "camera",
    "lights",
    "render",
    "lod",
    "wind",
    "lookdev",
    "ecosystem",
    "export",
)


class Config:
    """A parsed scene config.  Sections are validated lazily, on first use."""

    def __init__(self, data: dict, path: Path | None = None, base_dir: Path | None = None):
        self.data = data
        self.path = path
        self.base_dir = Path(base_dir if base_dir is not None else (path.parent if path else Path.cwd()))
        self.root = Fields(data, "", self, TOP_LEVEL_KEYS)

    # -- top level ---------------------------------------------------------
    @cached_property
    def seed(self) -> int:
        return self.root.integer("seed", 0, lo=0, hi=2**63 - 1)

    @cached_property
    def name(self) -> str:
        return self.root.string("name", self.path.stem if self.path else "scene")

    # -- scatter inputs ----------------------------------------------------
    @cached_property
    def terrain(self) -> TerrainConfig:
        f = self.root.sub("terrain", ("heightmap", "mesh", "procedural", "size", "height", "flat"))
        sources = [k for k in ("heightmap", "mesh", "procedural", "flat") if f.has(k)]
        if len(sources) > 1:
            f.fail(None, f"give exactly one terrain source, got {', '.join(sources)}")
        if not sources:
            f.fail(None, "give exactly one terrain source: heightmap, mesh or procedural")
        kind = sources[0]
        if kind == "heightmap":
            size = f.vector("size", 2, (1000.0, 1000.0), lo=0.0)
            if min(size) <= 0:
                f.fail("size", f"must be positive, got {list(size)}")
            return TerrainConfig(
                "heightmap", heightmap=f.file("heightmap"), size=size, height=f.number("height", 100.0, lo=0.0)
            )
        if kind == "mesh":
            for k in ("size", "height"):
                if f.has(k):
                    f.fail(k, "does not apply to a mesh terrain (the mesh is in metres, Y up)")
            return TerrainConfig("mesh", mesh=f.file("mesh"))
        if kind == "flat":
            p = f.sub("flat", ("size",))
            s = p.number("size", 1000.0, lo=0.0, lo_open=True)
            return TerrainConfig("flat", size=(s, s), height=0.0)
        p = f.sub("procedural", ("size", "height", "octaves", "resolution", "roughness", "seed"))
        size = p.number("size", 2000.0, lo=0.0, lo_open=True)
        return TerrainConfig(
            "procedural",
            size=(size, size),
            height=p.number("height", 150.0, lo=0.0),
            octaves=p.integer("octaves", 6, lo=1, hi=16),
            resolution=p.integer("resolution", 512, lo=8, hi=8192),
            roughness=p.number("roughness", 0.5, lo=0.0, hi=1.0),
            seed=p.integer("seed", self.seed, lo=0),
        )

    @cached_property
    def maps(self) -> MapsConfig:
        f = self.root.sub("maps", ("presence", "density", "colour", "partition", "presence_threshold", "moisture"))
        return MapsConfig(
            presence=f.file("presence"),
            density=f.file("density"),
            colour=f.file("colour"),
            partition=f.file("partition"),
            moisture=f.file("moisture"),
            presence_threshold=f.number("presence_threshold", 0.5, lo=0.0, hi=1.0),
        )

    @cached_property
    def partitions(self) -> tuple[Partition, ...]:
        f = self.root.sub("partitions")
        out = []
        tol = 0
        for key, name in f.table.items():
            if key == "tolerance":
                tol = f.integer("tolerance", 24, lo=0, hi=255)
                continue
            if not isinstance(name, str) or not name.strip() or not name.replace("_", "").replace("-", "").isalnum():
                f.fail(key, f"region name must be letters, digits, '-' or '_', got {name!r}")
            out.append(Partition(_parse_colour_label(key, f), name))
        names = [p.name for p in out]
        if len(set(names)) != len(names):
            f.fail(None, "region names must be unique")
        if len({p.colour for p in out}) != len(out):
            f.fail(None, "label colours must be unique")
        if out and self.maps.partition is None:
            f.fail(None, "regions are given but [maps] partition is not")
        self._partition_tolerance = tol if "tolerance" in f.table else 24
        return tuple(out)

    @property
    def partition_tolerance(self) -> int:
        self.partitions  # noqa: B018 - parsing the section sets the tolerance
        return self._partition_tolerance

    @cached_property
    def scatter(self) -> ScatterConfig:
        f = self.root.sub("scatter", ("count", "min_distance", "align_to_normal", "method"))
        return ScatterConfig(
            count=f.integer("count", 10000, lo=0, hi=MAX_TREES),
            min_distance=f.number("min_distance", 0.0, lo=0.0),
            align_to_normal=f.number("align_to_normal", 0.0, lo=0.0, hi=1.0),
            method=f.string("method", "random", choices=("random", "ecosystem")),
        )

    @cached_property
    def species(self) -> tuple[SpeciesConfig, ...]:
        items = self.data.get("species")
        if items is None:
            raise ConfigError(self.path, "species", "at least one [[species]] is required")
        if not isinstance(items, list) or not items:
            raise ConfigError(self.path, "species", "must be an array of tables ([[species]])")
        out = []
        known = (
            "model",
            "percent",
            "scale",
            "slope_max",
            "slope_min",
            "altitude",
            "align",
            "name",
            "yaw_step",
            "partitions",
            "moisture",
            "radius",
            "growth",
            "shade_tolerance",
            "lifespan",
            "vigour",
        )
        for i, item in enumerate(items):
            f = Fields(item, f"species[{i}]", self, known)
            out.append(
                SpeciesConfig(
                    model=f.string("model", required=True),
                    percent=f.number("percent", required=True, lo=0.0, hi=100.0),
                    scale=f.range("scale", (1.0, 1.0), lo=0.0),
                    slope_max=f.number("slope_max", 90.0, lo=0.0, hi=90.0),
                    slope_min=f.number("slope_min", 0.0, lo=0.0, hi=90.0),
                    altitude=f.range("altitude", None),
                    align=f.number("align", 0.0, lo=0.0, hi=1.0) if f.has("align") else None,
                    yaw_step=f.number("yaw_step", 0.0, lo=0.0, hi=360.0),
                    partitions=self._species_partitions(f),
                    extra={
                        k: v
                        for k, v in item.items()
                        if k
                        not in (
                            "model",
                            "percent",
                            "scale",
                            "slope_max",
                            "slope_min",
                            "altitude",
                            "align",
                            "yaw_step",
                            "partitions",
                        )
                    },
                )
            )
            if out[-1].scale[0] <= 0:
                f.fail("scale", f"must be positive, got {list(out[-1].scale)}")
            if out[-1].slope_min > out[-1].slope_max:
                f.fail("slope_min", "must not exceed slope_max")
        total = sum(s.percent for s in out)
        if total > 100.0 + 1e-9:
            raise ConfigError(self.path, "species", f"percentages add up to {total:g}, more than 100")
        return tuple(out)

    def _species_partitions(self, f: Fields) -> tuple[str, ...] | None:
        if not f.has("partitions"):
            return None
        v = f.table["partitions"]
        if not isinstance(v, list) or not v or not all(isinstance(x, str) for x in v):
            f.fail("partitions", f"must be a list of region names, got {v!r}")
        known = [p.name for p in self.partitions] + (["unlabelled"] if self.partitions else [])
        for name in v:
            if name not in known:
                f.fail("partitions", f"unknown region {name!r} (regions: {', '.join(known) or 'none'})")
        return tuple(v)

    # -- render inputs -----------------------------------------------------
    @cached_property
    def camera(self) -> CameraConfig:
        f = self.root.sub("camera", ("position", "target", "fov", "up", "keys", "shutter", "near", "far", "fps"))
        fov = f.number("fov", 40.0, lo=0.1, hi=179.0)
        keys = []
        raw_keys = f.table.get("keys", [])
        if not isinstance(raw_keys, list):
            f.fail("keys", "must be an array of tables")
        for i, k in enumerate(raw_keys):
            kf = Fields(k, f.path(f"keys[{i}]"), self, ("frame", "position", "target", "fov"))
            keys.append(
                CameraKey(
                    frame=kf.number("frame", required=True),
                    position=kf.vector("position", 3, required=True),
                    target=kf.vector("target", 3, required=True),
                    fov=kf.number("fov", fov, lo=0.1, hi=179.0),
                )
            )
        frames = [k.frame for k in keys]
        if frames != sorted(frames) or len(set(frames)) != len(frames):
            f.fail("keys", "frames must be strictly increasing")
        if keys:
            pos = f.vector("position", 3, keys[0].position)
            tgt = f.vector("target", 3, keys[0].target)
        else:
            size = max(self.terrain.size) if self.terrain.kind != "mesh" else 1000.0
            pos = f.vector("position", 3, (0.0, 0.15 * size, -0.6 * size))
            tgt = f.vector("target", 3, (0.0, 0.0, 0.0))
        if pos == tgt:
            f.fail("target", "must differ from position")
        near = f.number("near", 0.5, lo=0.0, lo_open=True)
        far = f.number("far", 100000.0, lo=near, lo_open=True)
        return CameraConfig(
            position=pos,
            target=tgt,
            fov=fov,
            up=f.vector("up", 3, (0.0, 1.0, 0.0)),
            keys=tuple(keys),
            shutter=f.number("shutter", 0.0, lo=0.0, hi=1.0),
            near=near,
            far=far,
            fps=f.number("fps", 24.0, lo=0.0, lo_open=True),
        )

    @cached_property
    def lights(self) -> LightsConfig:
        f = self.root.sub("lights", ("sun", "sky"))
        sun = None
        if f.has("sun") or not f.table:
            s = f.sub("sun", ("elevation", "azimuth", "irradiance", "colour"))
            sun = SunConfig(
                elevation=s.number("elevation", 35.0, lo=-90.0, hi=90.0),
                azimuth=s.number("azimuth", 120.0),
                irradiance=s.number("irradiance", 3.0, lo=0.0),
                colour=s.colour("colour", (1.0, 0.95, 0.88)),
            )
        sky = None
        if f.has("sky") or not f.table:
            s = f.sub("sky", ("radiance", "colour", "envmap", "scale", "sunsky", "turbidity", "albedo"))
            if s.has("envmap"):
                sky = SkyConfig("envmap", envmap=s.file("envmap"), scale=s.number("scale", 1.0, lo=0.0))
            elif s.has("sunsky"):
                ss = s.sub("sunsky", ("turbidity", "albedo", "scale"))
                sky = SkyConfig(
                    "sunsky",
                    turbidity=ss.number("turbidity", 3.0, lo=1.0, hi=10.0),
                    albedo=ss.number("albedo", 0.15, lo=0.0, hi=1.0),
                    scale=ss.number("scale", 1.0, lo=0.0),
                )
            else:
                sky = SkyConfig(
                    "constant", radiance=s.number("radiance", 0.35, lo=0.0), colour=s.colour("colour", (0.6, 0.75, 1.0))
                )
        return LightsConfig(sun=sun, sky=sky)

    @cached_property
    def render(self) -> RenderConfig:
        f = self.root.sub(
            "render",
            (
                "width",
                "height",
                "spp",
                "variant",
                "max_depth",
                "subframes",
                "haze",
                "haze_colour",
                "terrain_colour",
                "seed",
                "terrain_texture",
                "alpha_shadows",
            ),
        )
        return RenderConfig(
            width=f.integer("width", 1280, lo=1, hi=16384),
            height=f.integer("height", 720, lo=1, hi=16384),
            spp=f.integer("spp", 64, lo=1, hi=65536),
            variant=f.string("variant", None, choices=("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")),
            max_depth=f.integer("max_depth", 6, lo=1, hi=64),
            subframes=f.integer("subframes", 5, lo=1, hi=64),
            haze=f.number("haze", 0.0, lo=0.0),
            haze_colour=f.colour("haze_colour") if f.has("haze_colour") else None,
            terrain_colour=f.colour("terrain_colour", (0.18, 0.16, 0.11)),
            seed=f.integer("seed", 0, lo=0),
            terrain_texture=f.file("terrain_texture"),
            alpha_shadows=f.boolean("alpha_shadows", False),
        )

    @cached_property
    def lod(self) -> LodConfig:
        f = self.root.sub("lod", ("distances",))
        if not f.has("distances"):
            return LodConfig()
        d = f.table["distances"]
        if (
            not isinstance(d, list)
            or not 1 <= len(d) <= 3
            or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in d)
        ):
            f.fail("distances", f"must be a list of 1 to 3 numbers (metres), got {d!r}")
        d = tuple(float(x) for x in d)
        if any(not math.isfinite(x) or x <= 0 for x in d) or list(d) != sorted(set(d)):
            f.fail("distances", f"must be positive and strictly increasing, got {list(d)}")
        return LodConfig(distances=d, enabled=True)

    @cached_property
    def wind(self) -> WindConfig:
        f = self.root.sub("wind", ("strength", "frequency", "direction"))
        return WindConfig(
            strength=f.number("strength", 0.0, lo=0.0, hi=45.0),
            frequency=f.number("frequency", 0.4, lo=0.0),
            direction=f.number("direction", 0.0),
        )

    def section(self, name: str, known: Iterable[str] | None = None) -> Fields:
        """Raw accessor for sections other modules own (``lookdev``, ``ecosystem``, …)."""
        return self.root.sub(name, known)

    def validate_scatter(self) -> None:
        """Validate everything scatter reads (so errors surface before any work)."""
        self.seed, self.terrain, self.maps, self.partitions, self.scatter, self.species  # noqa: B018

    def validate_all(self) -> None:
        self.validate_scatter()
        self.camera, self.lights, self.render, self.lod, self.wind  # noqa: B018


def load_config(path: str | Path, overrides: dict | None = None) -> Config:
    """Read and parse a TOML scene config.  Raises :class:`ForestError` on any problem."""
    path = Path(path)
    if not path.is_file():
        raise ForestError(f"{path}: config file not found")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise ForestError(f"{path}: cannot read config: {e}") from None
    return parse_config(text, path=path.resolve(), overrides=overrides)


def parse_config(
    text: str, path: Path | None = None, base_dir: Path | None = None, overrides: dict | None = None
) -> Config:
    """Parse TOML text (e.g. received by the job service) into a :class:`Config`."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(path, None, f"invalid TOML: {e}") from None
    if overrides:
        for dotted, value in overrides.items():
            node = data
            *parents, last = dotted.split(".")
            for p in parents:
                node = node.setdefault(p, {})
            node[last] = value
    return Config(data, path=path, base_dir=base_dir)


def referenced_files(config: Config) -> list[Path]:
    """Every existing file the config names (terrain, maps, sky, textures, mesh species), sorted."""
    from .library.core import MESH_SUFFIXES

    found = [config.terrain.heightmap, config.terrain.mesh, config.render.terrain_texture]
    m = config.maps
    found += [m.presence, m.density, m.colour, m.partition, m.moisture]
    sky = config.lights.sky
    if sky is not None:
        found.append(sky.envmap)
    for sp in config.species:
        p = Path(sp.model).expanduser()
        if p.suffix.lower() in MESH_SUFFIXES:
            found.append(p if p.is_absolute() else config.base_dir / p)
    return sorted({Path(f) for f in found if f is not None and Path(f).is_file()})
