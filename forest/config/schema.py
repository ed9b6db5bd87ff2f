"""The scene file's schema: one pydantic model per TOML table, validated eagerly and strictly.

Every section of a scene file — the ones scatter and render read, and
``[lookdev]``, ``[ecosystem]`` and ``[export]`` — is declared here once, with
its types, ranges, defaults and a description.  From this one declaration
come: validation (numbers must be numbers, integers whole, strings strings,
unknown keys refused), the JSON Schema editors use to complete and check scene
files (``forest schema``), and the list of fields that name files
(:func:`file_fields`), so that the service, look-dev and ``forest examples``
never guess which strings are paths.

Types are strict: TOML already distinguishes integers, floats, booleans and
strings, so ``width = "64"`` or ``count = 1.5`` are mistakes, not values to coerce
(an integer is accepted where a float is expected).  Non-finite floats are
refused everywhere.

File fields hold paths relative to the scene file's folder; validation resolves
them (the :class:`pydantic.ValidationInfo` context carries ``base_dir``) and
checks that the file exists.
"""

from __future__ import annotations

import itertools
import math
import typing
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from ..errors import ForestError

MAX_TREES = 20_000_000
MAX_IMAGE_SIDE = 16384
MESH_SUFFIXES = (".obj", ".ply", ".gltf", ".glb", ".stl", ".off")


# ---------------------------------------------------------------------------
# Field types
# ---------------------------------------------------------------------------


def fail(message: str, field: str | None = None) -> PydanticCustomError:
    """A schema error with a finished message, optionally naming a sub-field of the table that raises it."""
    text = message.replace("{", "{{").replace("}", "}}")
    if field is None:
        return PydanticCustomError("forest", text)
    return PydanticCustomError("forest_field", text, {"field": field})


class FileRef:
    """Marks a field as naming an input file (relative to the scene file's folder)."""


def _resolve_file(value: Path, info: ValidationInfo) -> Path:
    base = (info.context or {}).get("base_dir")
    p = Path(value).expanduser()
    if not p.is_absolute() and base is not None:
        p = Path(base) / p
    if (info.context or {}).get("check_files", True) and not p.is_file():
        raise fail(f"file not found: {value}")
    return p


def _non_empty(value: str) -> str:
    if not value.strip():
        raise fail("must be a non-empty string")
    return value


Float = Annotated[float, Strict(False), Field(allow_inf_nan=False)]
Int = Annotated[int, Strict()]
Bool = Annotated[bool, Strict()]
Str = Annotated[str, Strict()]
NonNegative = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
Unit = Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]
RGB = tuple[NonNegative, NonNegative, NonNegative]
Vec3 = tuple[Float, Float, Float]
#: Largest coordinate or terrain extent, metres: float32 (every renderer's precision) spaces numbers 1 m apart at
#: 1e7 m, so beyond it a forest is meaningless; 1e308 once overflowed into infinities with an internal error.
WORLD_METRES = 1.0e7
Metres = Annotated[float, Strict(False), Field(ge=-WORLD_METRES, le=WORLD_METRES, allow_inf_nan=False)]
#: A point of the world (camera positions and targets), each coordinate within ±:data:`WORLD_METRES`.
Point3 = tuple[Metres, Metres, Metres]
#: A terrain's side or height, metres: positive (or ≥ 0) and at most :data:`WORLD_METRES`.
Extent = Annotated[float, Field(gt=0.0, le=WORLD_METRES, allow_inf_nan=False)]
ExtentOrZero = Annotated[float, Field(ge=0.0, le=WORLD_METRES, allow_inf_nan=False)]
InputFile = Annotated[Path, FileRef(), AfterValidator(_resolve_file), Field(json_schema_extra={"format": "path"})]


class Section(BaseModel):
    """A TOML table: unknown keys are refused, floats must be finite."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, validate_default=False, frozen=False)

    @model_validator(mode="before")
    @classmethod
    def _table(cls, data: Any) -> Any:
        if data is None:
            return {}
        if not isinstance(data, dict):
            raise fail(f"must be a table, got {data!r}")
        return data


def _ordered_pair(v: tuple[float, float] | None) -> tuple[float, float] | None:
    if v is not None and v[0] > v[1]:
        raise fail(f"first value must not exceed the second, got [{v[0]:g}, {v[1]:g}]")
    return v


# ---------------------------------------------------------------------------
# [terrain]
# ---------------------------------------------------------------------------


class ProceduralTerrain(Section):
    """Fractal value noise (fBm) over a square."""

    size: Extent = Field(2000.0, description="Side of the square, metres.")
    height: ExtentOrZero = Field(150.0, description="Height of the highest point, metres.")
    octaves: Annotated[Int, Field(ge=1, le=16)] = Field(6, description="Noise lattices, each twice as fine.")
    resolution: Annotated[Int, Field(ge=8, le=8192)] = Field(512, description="Grid vertices per side.")
    roughness: Unit = Field(0.5, description="Strength of each octave relative to the previous one.")
    seed: Annotated[Int, Field(ge=0)] | None = Field(None, description="Noise seed (default: the scene's seed).")


class FlatTerrain(Section):
    """A flat square at height 0."""

    size: Extent = Field(1000.0, description="Side of the square, metres.")


class WaterLevel(Section):
    """Still water at one height: a lake, a reservoir or the sea over the terrain's lower ground."""

    level: Metres = Field(description="Height of the water's surface, metres (the terrain's own heights).")
    shore: Annotated[float, Field(ge=0.0, le=1000.0, allow_inf_nan=False)] = Field(
        0.5, description="Metres above the water kept free of trees and ground cover (their roots stay dry)."
    )


class TerrainConfig(Section):
    """Exactly one source: ``heightmap`` (with ``size`` and ``height``), ``mesh``, ``procedural`` or ``flat``."""

    heightmap: InputFile | None = Field(
        None, description="Greyscale image (8/16-bit PNG, TIFF, EXR); white = `height` metres."
    )
    mesh: InputFile | None = Field(None, description="Terrain mesh trimesh reads, metres, Y up.")
    procedural: ProceduralTerrain | None = None
    flat: FlatTerrain | None = None
    size: tuple[Extent, Extent] = Field((1000.0, 1000.0), description="Heightmap extent along X and Z, metres.")
    height: ExtentOrZero = Field(100.0, description="Heightmap: metres at full white.")
    water: WaterLevel | None = Field(
        None,
        description=(
            "Still water: the terrain below `level` becomes a flat water surface (the ground's `water` material), "
            "no tree or ground cover stands within `shore` metres above it."
        ),
    )

    @model_validator(mode="after")
    def _one_source(self) -> TerrainConfig:
        sources = [k for k in ("heightmap", "mesh", "procedural", "flat") if getattr(self, k) is not None]
        if len(sources) != 1:
            got = f", got {', '.join(sources)}" if sources else ""
            raise fail(f"give exactly one terrain source: heightmap, mesh, procedural or flat{got}")
        if self.heightmap is None:
            for key in ("size", "height"):
                if key in self.model_fields_set:
                    raise fail(f"does not apply to a {sources[0]} terrain (only to a heightmap)", key)
        return self

    @property
    def kind(self) -> str:
        """``"heightmap"``, ``"mesh"``, ``"procedural"`` or ``"flat"``."""
        for k in ("heightmap", "mesh", "procedural", "flat"):
            if getattr(self, k) is not None:
                return k
        raise AssertionError("validated terrain has a source")

    @property
    def extent_size(self) -> tuple[float, float] | None:
        """(X, Z) extent in metres for grid terrains; None for a mesh (known once loaded)."""
        if self.procedural is not None:
            return (self.procedural.size, self.procedural.size)
        if self.flat is not None:
            return (self.flat.size, self.flat.size)
        if self.heightmap is not None:
            return self.size
        return None


# ---------------------------------------------------------------------------
# [maps], [partitions]
# ---------------------------------------------------------------------------


class MapsConfig(Section):
    """Painted maps laid over the terrain's X/Z extent (column → +X, row → +Z, row 0 at the smallest Z)."""

    presence: InputFile | None = Field(None, description="White = trees allowed.")
    density: InputFile | None = Field(None, description="Grey level = relative density.")
    colour: InputFile | None = Field(
        None, description="sRGB tint map (→ linear), a tint around each species' leaf colour."
    )
    colour_normalise: Literal["rgb", "luminance", "none"] = Field(
        "rgb",
        description=(
            "How the colour map becomes a tint: 'rgb' divides each linear channel by its mean over the terrain "
            "(mean tint 1: the species' own colour on average), 'luminance' divides by the mean luminance "
            "(keeps the map's overall hue), 'none' uses the values as painted (an absolute multiplier)."
        ),
    )
    partition: InputFile | None = Field(None, description="Label colours → regions (see [partitions]).")
    moisture: InputFile | None = Field(None, description="Grey = soil moisture, for method = 'ecosystem'.")
    presence_threshold: Unit = Field(0.5, description="Presence grey level at which trees are allowed.")


def parse_label(key: str) -> tuple[int, int, int] | None:
    """``"#ff0000"`` or ``"#f00"`` → (255, 0, 0); None if it is not a colour."""
    t = key.strip().lstrip("#")
    if len(t) == 3:
        t = "".join(c * 2 for c in t)
    if len(t) != 6:
        return None
    try:
        return int(t[0:2], 16), int(t[2:4], 16), int(t[4:6], 16)
    except ValueError:
        return None


class PartitionsConfig(Section):
    """Label colour → region name (``"#ff0000" = "foreground"``), any number, plus ``tolerance``."""

    model_config = ConfigDict(
        extra="allow",
        json_schema_extra={
            "patternProperties": {"^#?([0-9a-fA-F]{3}|[0-9a-fA-F]{6})$": {"type": "string"}},
            "additionalProperties": False,
        },
    )
    __pydantic_extra__: dict[str, Any] = Field(init=False)

    tolerance: Annotated[Int, Field(ge=0, le=255)] = Field(
        24, description="Largest per-channel difference (8-bit) between a pixel and its label colour."
    )

    @model_validator(mode="after")
    def _labels(self) -> PartitionsConfig:
        names: list[str] = []
        colours: list[tuple[int, int, int]] = []
        for key, name in (self.__pydantic_extra__ or {}).items():
            c = parse_label(key)
            if c is None:
                raise fail('partition keys must be colours like "#ff0000"', key)
            if not isinstance(name, str) or not name.strip() or not name.replace("_", "").replace("-", "").isalnum():
                raise fail(f"region name must be letters, digits, '-' or '_', got {name!r}", key)
            names.append(name)
            colours.append(c)
        if len(set(names)) != len(names):
            raise fail("region names must be unique")
        if len(set(colours)) != len(colours):
            raise fail("label colours must be unique")
        return self

    @property
    def labels(self) -> tuple[tuple[tuple[int, int, int], str], ...]:
        """((8-bit sRGB colour, region name), …) in file order."""
        out = []
        for key, name in (self.__pydantic_extra__ or {}).items():
            c = parse_label(key)
            assert c is not None
            out.append((c, name))
        return tuple(out)


# ---------------------------------------------------------------------------
# [scatter], [[species]], [ecosystem]
# ---------------------------------------------------------------------------


class Clumping(Section):
    """Stand-scale structure (:mod:`forest.scatter.canopy`): denser stands, thinner edges and clearings."""

    scale: Positive = Field(50.0, description="Wavelength of the stand noise, metres (stands and clearings ~ this).")
    strength: Unit = Field(0.5, description="0 even … 1: how much the thinnest stands are thinned (density 1 - s).")
    clearings: Annotated[float, Field(ge=0.0, le=0.9, allow_inf_nan=False)] = Field(
        0.07, description="Share of the terrain's area left as clearings with soft edges (0.07 = 7 %)."
    )


class Emergents(Section):
    """A tail of tall trees above the canopy: a share of trees scaled by a factor drawn uniformly in ``scale``."""

    fraction: Unit = Field(0.025, description="Share of trees that are emergents.")
    scale: tuple[Positive, Positive] = Field((1.3, 1.6), description="Extra scale factor range [min, max].")

    _pairs = field_validator("scale")(_ordered_pair)


class Grouping(Section):
    """Trees of one species in groups and patches instead of evenly mixed (:mod:`forest.scatter.canopy`)."""

    strength: Unit = Field(
        0.0, description="0 evenly mixed (off) … 1 each patch one species; every species keeps its percent."
    )
    scale: Positive = Field(60.0, description="Wavelength of the groups' noise, metres (groups ~ half this across).")


class EdgeTaper(Section):
    """Trees smaller along the edge of the presence map, stepping up to the canopy (:mod:`forest.scatter.canopy`)."""

    width: Annotated[float, Field(gt=0.0, le=10000.0, allow_inf_nan=False)] = Field(
        20.0, description="Metres inside the presence map's edge at which trees reach their full size."
    )
    scale: Annotated[float, Field(gt=0.0, le=1.0, allow_inf_nan=False)] = Field(
        0.5, description="Scale factor of a tree on the edge (and outside it), rising smoothly to 1 at width."
    )


class ScatterConfig(Section):
    """Candidate sites over the terrain and how trees are kept: by percentages (random) or by growth (ecosystem)."""

    count: Annotated[Int, Field(ge=0, le=MAX_TREES)] = Field(
        10000, description="Candidate sites over the whole terrain (all maps white)."
    )
    min_distance: NonNegative = Field(0.0, description="> 0: Poisson-disk spacing between trees, metres.")
    align_to_normal: Unit = Field(0.0, description="0 upright … 1 along the terrain normal.")
    method: Literal["random", "ecosystem"] = Field(
        "random", description="'random': percentages; 'ecosystem': growth, competition and self-thinning."
    )
    clumping: Clumping = Field(
        default_factory=Clumping, description="Stands and clearings; strength = 0 and clearings = 0 turn it off."
    )
    emergents: Emergents = Field(
        default_factory=Emergents, description="Tall trees above the canopy; fraction = 0: off."
    )
    grouping: Grouping = Field(
        default_factory=Grouping,
        description="Species in groups and patches (strength > 0) rather than evenly mixed; percentages kept.",
    )
    edge_taper: EdgeTaper | None = Field(
        None,
        description="Smaller trees along the edge of [maps] presence, a forest mantle stepping up to the canopy "
        "(off by default).",
    )


Range = tuple[Float, Float]
#: Individuals drawn per generated library species when ``individuals`` is not given (a mesh has one).
DEFAULT_INDIVIDUALS = 4
MAX_INDIVIDUALS = 255  # the InstanceSet's ``individual`` column is uint8


class ColourJitter(Section):
    """Per-tree colour variation: a hue rotation and a lightness scale in OkLCh, uniform in ± the given amounts."""

    hue: Annotated[float, Field(ge=0.0, le=180.0, allow_inf_nan=False)] = Field(
        11.0, description="Largest hue rotation, degrees of OkLCh hue."
    )
    value: Annotated[float, Field(ge=0.0, le=0.9, allow_inf_nan=False)] = Field(
        0.18, description="Largest relative change of Oklab lightness L (0.18 = ±18 %)."
    )


#: Most colour accents a species may carry (:class:`Accent`).
MAX_ACCENTS = 8


class Accent(Section):
    """A share of a species' trees whose leaves turn toward another colour (:func:`forest.tint.tree_tints`).

    Real canopies are not one green with jitter: from above a tropical forest shows the red and
    bronze of crowns flushing new leaves and the yellow of flowering ones, a summer spruce forest a
    few yellowing or beetle-killed brown crowns, a mixed wood in autumn whole crowns of yellow and
    orange.  An accent mixes a tree's leaf colour toward ``colour`` by a weight drawn per tree in
    ``amount``, in Oklab, before the tree's own hue/value jitter."""

    share: Unit = Field(description="Share of the species' trees that carry this accent (0.03 = 3 %).")
    colour: RGB = Field(description="The accent's leaf albedo, linear RGB, each channel at most 0.9.")
    amount: tuple[Unit, Unit] = Field(
        (0.7, 1.0), description="Range [lo, hi] of the mix toward the colour, drawn per tree (1 = the colour itself)."
    )
    clustering: Unit = Field(
        0.0,
        description="0: the accented trees stand anywhere; toward 1 they gather in patches (a beetle outbreak's "
        "spots), the share kept over the terrain.",
    )
    patch_scale: Annotated[float, Field(gt=0.0, le=100000.0, allow_inf_nan=False)] = Field(
        80.0, description="Size of those patches, metres (the wavelength of their noise)."
    )

    _pairs = field_validator("amount")(_ordered_pair)

    @field_validator("colour")
    @classmethod
    def _albedo(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if max(v) > 0.9:
            raise fail(f"each channel is a leaf albedo, at most 0.9, got {list(v)}")
        return v


def _accent_shares(v: tuple[Accent, ...]) -> tuple[Accent, ...]:
    """A species' accents: their shares add up to at most 1 (a tree carries one accent at most)."""
    total = sum(a.share for a in v)
    if total > 1.0 + 1e-9:
        raise fail(f"the accents' shares add up to {total:g}, more than 1")
    return v


#: The default moss colour (:class:`BarkLook`): linear sRGB of a dull olive green, about 8 % luminance.
MOSS_COLOUR = (0.055, 0.085, 0.03)


class BarkLook(Section):
    """Per-tree bark variation: a hue rotation and lightness scale in OkLCh as :class:`ColourJitter`, then a
    share of moss mixed in, uniform in ``moss`` = [lo, hi] (:func:`forest.tint.bark_tints`)."""

    hue: Annotated[float, Field(ge=0.0, le=180.0, allow_inf_nan=False)] = Field(
        6.0, description="Largest hue rotation of the bark, degrees of OkLCh hue."
    )
    value: Annotated[float, Field(ge=0.0, le=0.9, allow_inf_nan=False)] = Field(
        0.15, description="Largest relative change of the bark's Oklab lightness L (0.15 = ±15 %)."
    )
    moss: tuple[Unit, Unit] = Field(
        (0.0, 0.25), description="Range [lo, hi] of the share of the bark covered by moss, drawn per tree."
    )
    moss_colour: RGB = Field(MOSS_COLOUR, description="The moss's albedo, linear RGB.")

    _pairs = field_validator("moss")(_ordered_pair)

    @property
    def varies(self) -> bool:
        """Whether any tree's bark differs from the species' colour."""
        return self.hue > 0 or self.value > 0 or self.moss[1] > 0


def is_mesh_model(model: str) -> bool:
    """True when a ``model`` string names a mesh file rather than a library species."""
    return Path(model).suffix.lower() in MESH_SUFFIXES


def individual_count(model: str, individuals: int | None) -> int:
    """Individuals a species or ground cover draws from: ``individuals``, else 4 (a library species) or 1 (a mesh)."""
    if individuals is not None:
        return individuals
    return 1 if is_mesh_model(model) else DEFAULT_INDIVIDUALS


def check_slopes(slope_min: float, slope_max: float) -> None:
    """``slope_min`` must not exceed ``slope_max`` (an error naming ``slope_min``)."""
    if slope_min > slope_max:
        raise fail("must not exceed slope_max", "slope_min")


class SpeciesConfig(Section):
    """One ``[[species]]``: a library tree, its share and where it grows."""

    model: Annotated[Str, Field(min_length=1)] = Field(
        description="A library name, NAME@SEED, or a mesh file (relative to the scene file)."
    )
    percent: Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)] = Field(
        description="Share of candidates; the remainder of 100 % is empty ground."
    )
    name: Str | None = Field(None, description="A label for reports (default: the model).")
    scale: tuple[Positive, Positive] = Field((1.0, 1.0), description="Uniform scale range [min, max].")
    slope_max: Annotated[float, Field(ge=0.0, le=90.0, allow_inf_nan=False)] = Field(
        90.0, description="Steepest terrain, degrees."
    )
    slope_min: Annotated[float, Field(ge=0.0, le=90.0, allow_inf_nan=False)] = Field(
        0.0, description="Flattest terrain, degrees."
    )
    altitude: Range | None = Field(None, description="Height window [min, max], metres.")
    align: Unit | None = Field(None, description="Overrides [scatter] align_to_normal for this species.")
    yaw_step: Annotated[float, Field(ge=0.0, le=360.0, allow_inf_nan=False)] = Field(
        0.0, description="> 0 snaps yaw to multiples of this many degrees (street-aligned buildings)."
    )
    partitions: Annotated[tuple[Annotated[Str, Field(min_length=1)], ...], Field(min_length=1)] | None = Field(
        None, description="Regions of [partitions] this species may grow in (default: all)."
    )
    # Ecosystem method (Deussen et al. 1998)
    radius: Positive = Field(4.0, description="Ecosystem: mature radius of the zone of influence, metres.")
    growth: Positive = Field(0.25, description="Ecosystem: growth rate, 1/year.")
    shade_tolerance: Unit = Field(0.0, description="Ecosystem: >= 0.5 survives beneath a larger canopy.")
    vigour: Positive = Field(1.0, description="Ecosystem: competitive strength multiplier.")
    moisture: tuple[Unit, Unit] = Field((0.0, 1.0), description="Ecosystem: preferred soil moisture [lo, hi].")
    # Look
    individuals: Annotated[Int, Field(ge=1, le=MAX_INDIVIDUALS)] | None = Field(
        None,
        description=f"Different trees of this species drawn per tree (default {DEFAULT_INDIVIDUALS} for a generated "
        "library species, 1 for a mesh).",
    )
    colour_jitter: ColourJitter = Field(default_factory=ColourJitter, description="Per-tree hue and value variation.")
    bark: BarkLook = Field(default_factory=BarkLook, description="Per-tree bark hue, value and moss.")
    accents: Annotated[tuple[Accent, ...], Field(max_length=MAX_ACCENTS)] = Field(
        (),
        description="Shares of the trees whose leaves turn toward another colour (flushing, flowering, "
        "yellowing, beetle-killed crowns), e.g. [{ share = 0.03, colour = [0.25, 0.06, 0.03] }].",
    )
    dead: Unit = Field(
        0.0,
        description="Share of trees standing dead (snags: the tree without its leaves; e.g. 0.02); forest's "
        "renderers draw them, the exports draw the living tree.",
    )

    _pairs = field_validator("scale", "altitude", "moisture")(_ordered_pair)
    _accents = field_validator("accents")(_accent_shares)

    @model_validator(mode="after")
    def _slopes(self) -> SpeciesConfig:
        check_slopes(self.slope_min, self.slope_max)
        if self.dead > 0 and self.individual_count > MAX_INDIVIDUALS // 2:
            raise fail(f"needs individuals <= {MAX_INDIVIDUALS // 2} (snags take the upper half), or dead = 0", "dead")
        return self

    @property
    def is_mesh(self) -> bool:
        """True when ``model`` names a mesh file rather than a library species."""
        return is_mesh_model(self.model)

    @property
    def individual_count(self) -> int:
        """How many individuals scatter draws from (:func:`individual_count`)."""
        return individual_count(self.model, self.individuals)


class EcosystemConfig(Section):
    """The ``ecosystem`` scatter method: years of growth and competition, and the fitness a seed needs."""

    steps: Annotated[Int, Field(ge=1, le=200)] = Field(15, description="Years of growth and competition.")
    establish: Unit = Field(0.25, description="Site fitness below which a seed never establishes.")


# ---------------------------------------------------------------------------
# [ground], [[ground_cover]]
# ---------------------------------------------------------------------------

#: Built-in ground materials: linear sRGB albedo (D65) in the visible band.  Shapes of the spectra after
#: the USGS Spectral Library Version 7 (Kokaly et al. 2017, USGS Data Series 1035) and the ECOSTRESS
#: library (Meerdink et al. 2019, Remote Sens. Environ. 230: 111196), scaled to the broadband albedos
#: tabulated by Oke (1987, "Boundary Layer Climates", table 1.1: grass 0.16–0.26, dry soil 0.2–0.35,
#: wet soil 0.05–0.15, sand 0.3–0.4, fresh snow 0.8–0.95); a grass sward reflects little in the visible
#: (its broadband albedo is carried by the near infrared), wetting about halves a soil's reflectance
#: (Lobell & Asner 2002, Soil Sci. Soc. Am. J. 66: 722–727).
GROUND_MATERIALS: dict[str, tuple[float, float, float]] = {
    "grass": (0.050, 0.090, 0.030),  # green sward seen from above
    "dry_grass": (0.200, 0.165, 0.090),  # senescent grass, straw
    "soil": (0.190, 0.140, 0.090),  # dry loam
    "litter": (0.110, 0.075, 0.045),  # leaf and needle litter under a canopy
    "rock": (0.220, 0.210, 0.190),  # weathered granite, gneiss
    "wet": (0.075, 0.062, 0.048),  # wet soil, mud, riverbed
    "sand": (0.400, 0.330, 0.240),  # dry quartz sand
    "snow": (0.850, 0.870, 0.900),  # fresh snow
    # Open water where its bed is out of sight (the deep water's colour; shallower water shows its bed, [ground]
    # water_attenuation): as dark as half a metre of river water over wet gravel, ρ_bed ⊙ exp(−2 σ_a d)
    # (Beer–Lambert down and up), ρ_bed = (0.10, 0.09, 0.07), d = 0.5 m, σ_a = WATER_ATTENUATION.  forest_path
    # adds the surface's Fresnel mirror over it (``[ground]`` rules of this material); other renderers show this
    # colour only.
    "water": (0.067, 0.074, 0.045),
}
#: River water's attenuation per metre (RGB): pure water (Pope & Fry 1997, Appl. Opt. 36: 8710) plus yellow
#: substance (Bricaud et al. 1981, Limnol. Oceanogr. 26: 43); a Secchi disc vanishes at about 1.7/K (Poole &
#: Atkins 1929), 8.5 m in the green.
WATER_ATTENUATION = (0.40, 0.20, 0.45)
#: Fall of a painted river's bed from its edge toward its middle, metres of depth per metre (:mod:`forest.ground`).
BANK_GRADIENT = 0.15
#: Refractive index of water in the visible band (1.333 at 589 nm, 20 °C; Hale & Querry 1973, Appl. Opt. 12: 555).
WATER_IOR = 1.33
#: The ground material that forest_path renders as a water surface (a rule painting it marks water).
WATER_MATERIAL = "water"
MATERIAL_NAME = r"^[A-Za-z][A-Za-z0-9_-]{0,63}$"


def _window(v: list[float]) -> tuple[float, ...]:
    if len(v) == 3:
        raise fail(f"give [lo, hi] or a ramp [lo0, lo1, hi1, hi0], got {len(v)} values")
    if any(b < a for a, b in itertools.pairwise(v)):
        raise fail(f"values must not decrease, got [{', '.join(f'{x:g}' for x in v)}]")
    return tuple(v)


Window = Annotated[list[Float], Field(min_length=2, max_length=4), AfterValidator(_window)]


class GroundRule(Section):
    """One layer of the ground: ``material`` painted over the layers before it where every window holds.

    A window is ``[lo, hi]`` (a smooth step of a default width centred on each edge) or an explicit ramp
    ``[lo0, lo1, hi1, hi0]`` (0 below lo0, rising to 1 at lo1, 1 until hi1, falling to 0 at hi0).
    """

    material: Annotated[Str, Field(min_length=1)] = Field(description="A name from [ground.materials].")
    slope: Window | None = Field(None, description="Terrain slope window, degrees.")
    altitude: Window | None = Field(None, description="Height window, metres.")
    moisture: Window | None = Field(
        None, description="Soil moisture window in [0, 1]: [maps] moisture, else low and flat ground is wet."
    )
    canopy: Window | None = Field(None, description="Tree crown cover window in [0, 1] (0 open ground, 1 closed).")
    relief: Window | None = Field(
        None, description="Height above the lowest ground within [ground] relief_radius, metres (valley floors: 0)."
    )
    map: InputFile | None = Field(None, description="Grey weight image over the extent (map convention).")
    invert: Bool = Field(False, description="Use 1 − the map's grey level.")
    opacity: Unit = Field(1.0, description="Strength of the layer.")
    noise: NonNegative = Field(0.5, description="Breaks up the edges: they wander by about this many ramp widths.")
    noise_scale: Positive = Field(25.0, description="Size of the edge breakup, metres.")


class GroundConfig(Section):
    """The terrain's materials: ``base`` everywhere, then each of ``rules`` painted over it in order."""

    materials: dict[Annotated[Str, Field(pattern=MATERIAL_NAME)], RGB] = Field(
        default_factory=dict,
        description=(
            "Name → linear RGB albedo; adds to or overrides the built-in grass, dry_grass, soil, litter, rock, "
            "wet, sand, snow and water (forest_path: a Fresnel mirror over this colour)."
        ),
    )
    base: Annotated[Str, Field(min_length=1)] = Field("soil", description="The material under every rule.")
    rules: list[GroundRule] | None = Field(
        None, description="Layers in order (default: grass on gentle open ground, litter under trees, rock on steep)."
    )
    resolution: Annotated[Int, Field(ge=2, le=8192)] = Field(
        1024, description="Albedo texels along the longer side of the terrain."
    )
    detail_tile: NonNegative = Field(4.0, description="Metres per repeat of the detail texture (0: no detail).")
    detail_strength: Annotated[float, Field(ge=0.0, le=2.0, allow_inf_nan=False)] = Field(
        1.0, description="Contrast of the detail texture (0 flat, 1 as drawn)."
    )
    relief_radius: Positive = Field(30.0, description="Metres around a point that rules' relief looks for the floor.")
    variation: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = Field(
        0.12,
        description="Patches of lighter and darker, warmer and cooler ground over the rules' materials: the "
        "standard deviation of the albedo's logarithm (0: each material one colour).",
    )
    variation_scale: Positive = Field(20.0, description="Size of those patches, metres.")
    water_ripple: Annotated[float, Field(ge=0.0, le=20.0, allow_inf_nan=False)] = Field(
        2.0, description="Ripples on water (rules of material water): RMS tilt of its mirror, degrees (0 flat)."
    )
    water_attenuation: RGB = Field(
        WATER_ATTENUATION,
        description="How fast water hides its bed: attenuation per metre of depth (RGB; a Secchi disc vanishes at "
        "about 1.7 / this). Shallow water shows the ground painted under it, deep water the water material's colour.",
    )
    water_depth: NonNegative = Field(
        2.0,
        description="Deepest water of rules of material water, metres: the bed falls from the water's edge at "
        f"{BANK_GRADIENT} m per metre down to this (0: the water material's colour everywhere). [terrain] water "
        "knows its own depth.",
    )

    @model_validator(mode="after")
    def _names(self) -> GroundConfig:
        known = {**GROUND_MATERIALS, **self.materials}
        names = ", ".join(sorted(known))
        if self.base not in known:
            raise fail(f"unknown material {self.base!r} (materials: {names})", "base")
        for i, rule in enumerate(self.rules or ()):
            if rule.material not in known:
                raise fail(f"unknown material {rule.material!r} (materials: {names})", f"rules[{i}].material")
        return self

    def palette(self) -> dict[str, tuple[float, float, float]]:
        """Every material by name: the built-in ones, then ``materials`` (which may override them)."""
        return {**GROUND_MATERIALS, **{k: (float(v[0]), float(v[1]), float(v[2])) for k, v in self.materials.items()}}


class CoverClumping(Section):
    """Patches of one ``[[ground_cover]]`` (:mod:`forest.scatter.ground_cover`): density ×(1 + s(2U − 1)), same mean."""

    strength: Unit = Field(
        0.0, description="0 even … 1: density varies from (1 - s) to (1 + s) times `density` between patches."
    )
    scale: Positive = Field(6.0, description="Wavelength of the patch noise, metres (patches ~ half this across).")
    size: Annotated[float, Field(ge=0.0, le=0.9, allow_inf_nan=False)] = Field(
        0.0, description="Plants in the densest patches (1 + size) times larger, in the thinnest (1 - size) times."
    )


class GroundCoverConfig(Section):
    """One ``[[ground_cover]]``: small plants (grass, fern clumps) scattered near the camera path at a density."""

    model: Annotated[Str, Field(min_length=1)] = Field(
        description="A library name, NAME@SEED, or a mesh file (relative to the scene file)."
    )
    density: Annotated[float, Field(gt=0.0, le=1000.0, allow_inf_nan=False)] = Field(
        description="Plants per square metre of terrain surface."
    )
    max_distance: Annotated[float, Field(gt=0.0, le=100000.0, allow_inf_nan=False)] = Field(
        60.0,
        description="Within this many metres of the camera (any point of its path), thinning out over the last 30 %.",
    )
    name: Str | None = Field(None, description="A label for reports (default: the model).")
    scale: tuple[Positive, Positive] = Field((0.8, 1.2), description="Uniform scale range [min, max].")
    slope_max: Annotated[float, Field(ge=0.0, le=90.0, allow_inf_nan=False)] = Field(
        40.0, description="Steepest terrain, degrees."
    )
    slope_min: Annotated[float, Field(ge=0.0, le=90.0, allow_inf_nan=False)] = Field(
        0.0, description="Flattest terrain, degrees."
    )
    altitude: Range | None = Field(None, description="Height window [min, max], metres.")
    presence: Bool = Field(True, description="Grow only where [maps] presence allows trees.")
    align: Unit = Field(0.7, description="0 upright … 1 along the terrain normal.")
    individuals: Annotated[Int, Field(ge=1, le=MAX_INDIVIDUALS)] | None = Field(
        None, description=f"Different plants drawn (default {DEFAULT_INDIVIDUALS} for a library species, 1 for a mesh)."
    )
    colour_jitter: ColourJitter = Field(default_factory=ColourJitter, description="Per-plant hue and value variation.")
    bark: BarkLook = Field(default_factory=BarkLook, description="Per-plant bark hue, value and moss.")
    accents: Annotated[tuple[Accent, ...], Field(max_length=MAX_ACCENTS)] = Field(
        (),
        description="Shares of the plants whose leaves turn toward another colour (flushing, flowering, "
        "yellowing, beetle-killed crowns), e.g. [{ share = 0.03, colour = [0.25, 0.06, 0.03] }].",
    )
    clumping: CoverClumping = Field(
        default_factory=CoverClumping,
        description="Patches: the density varies over a noise field with the mean kept; strength = 0 turns it off.",
    )
    edge: Annotated[float, Field(gt=0.0, le=10000.0, allow_inf_nan=False)] | None = Field(
        None,
        description="Metres: grow only this close to the edge of [maps] presence, on both sides "
        "(a shrub mantle; with presence = true only the inner side).",
    )
    water_edge: Bool = Field(
        False,
        description="Grow down to the edge of still water ([terrain] water), as reeds and sedges do: "
        "its shore keeps this cover off the water only, not off the bank above it.",
    )

    _pairs = field_validator("scale", "altitude")(_ordered_pair)
    _accents = field_validator("accents")(_accent_shares)

    @model_validator(mode="after")
    def _slopes(self) -> GroundCoverConfig:
        check_slopes(self.slope_min, self.slope_max)
        return self

    @property
    def is_mesh(self) -> bool:
        """True when ``model`` names a mesh file rather than a library species."""
        return is_mesh_model(self.model)

    @property
    def individual_count(self) -> int:
        """How many individuals scatter draws from (:func:`individual_count`)."""
        return individual_count(self.model, self.individuals)


#: Most ``[[tree]]`` entries a scene may place by hand.
MAX_PLACED_TREES = 10_000


class PlacedTree(Section):
    """One ``[[tree]]``: a tree placed by hand — a specimen in a meadow, a hero tree by the camera.

    It is one of a ``[[species]]``' trees (its individuals, colour jitter, accents and bark), stands where
    ``position`` says whatever the maps say, and clears the scattered trees around its trunk.
    """

    species: Annotated[Str, Field(min_length=1)] = Field(
        description="The [[species]] it is one of: that entry's name, or its model."
    )
    position: tuple[Metres, Metres] = Field(
        description="[x, z] of the trunk's base, metres; it stands on the terrain there."
    )
    scale: Positive = Field(1.0, description="Uniform scale (1: the library tree's own size).")
    yaw: Annotated[float, Field(ge=0.0, le=360.0, allow_inf_nan=False)] | None = Field(
        None, description="Degrees about +Y (default: drawn from the seed)."
    )
    individual: Annotated[Int, Field(ge=0, le=MAX_INDIVIDUALS - 1)] | None = Field(
        None, description="Which individual of its species, 0 … individuals − 1 (default: drawn from the seed)."
    )
    clear: Annotated[float, Field(ge=0.0, le=10000.0, allow_inf_nan=False)] | None = Field(
        None,
        description="Scattered trees standing within this many metres of it are left out (default: its crown's "
        "radius, the highest level's horizontal reach times scale; 0 keeps them all).",
    )
    dead: Bool = Field(
        False,
        description="A standing dead tree (a snag: the tree without its leaves), as [[species]] dead draws; "
        "forest's renderers draw it, the exports the living tree.",
    )


def species_index(species: typing.Sequence[SpeciesConfig], ref: str) -> int:
    """The ``[[species]]`` entry a ``[[tree]]``'s ``species`` names: by ``name``, else by ``model``.

    Raises :class:`ValueError` (a finished sentence) when none or several entries match.
    """
    for key in ("name", "model"):
        hits = [i for i, sp in enumerate(species) if getattr(sp, key) == ref]
        if len(hits) == 1:
            return hits[0]
        if len(hits) > 1:
            raise ValueError(
                f"{ref!r} is the {key} of species[{hits[0]}] and species[{hits[1]}]; give them names and use one"
            )
    known = ", ".join(sorted({sp.name or sp.model for sp in species}))
    raise ValueError(f"no [[species]] is named {ref!r} (species: {known})")


# ---------------------------------------------------------------------------
# [camera]
# ---------------------------------------------------------------------------

Fov = Annotated[float, Field(ge=0.1, le=179.0, allow_inf_nan=False)]
#: A lens's focal length, millimetres (a 4 mm fisheye to a 10 m mirror telescope).
FocalLength = Annotated[float, Field(ge=0.1, le=10000.0, allow_inf_nan=False)]
#: A filmback's width (horizontal aperture), millimetres (a phone's 5 mm to an 8×10 inch plate's 254 mm).
SensorWidth = Annotated[float, Field(ge=0.1, le=1000.0, allow_inf_nan=False)]
#: Full-frame 35 mm stills: 36 × 24 mm.
FULL_FRAME_MM = 36.0
#: A lens's f-number N = focal length / aperture diameter (f/0.7, the fastest lenses made, to a pinhole-like f/256).
FStop = Annotated[float, Field(ge=0.7, le=256.0, allow_inf_nan=False)]
#: Metres from the lens to the plane in focus, along the view axis.
FocusDistance = Annotated[float, Field(gt=0.0, le=1.0e6, allow_inf_nan=False)]


def fov_from_focal_length(focal_length: float, sensor_width: float) -> float:
    """Horizontal field of view, degrees, of a ``focal_length`` mm lens on a ``sensor_width`` mm filmback:
    2·atan(sensor_width / (2·focal_length))."""
    return math.degrees(2.0 * math.atan(sensor_width / (2.0 * focal_length)))


def focal_length_from_fov(fov: float, sensor_width: float) -> float:
    """Focal length, millimetres, that gives a horizontal ``fov`` (degrees) on a ``sensor_width`` mm filmback."""
    return (sensor_width / 2.0) / math.tan(math.radians(fov) / 2.0)


def _lens_fov(focal_length: float, sensor_width: float, field: str) -> float:
    fov = fov_from_focal_length(focal_length, sensor_width)
    if not 0.1 <= fov <= 179.0:
        raise fail(
            f"{focal_length:g} mm on a {sensor_width:g} mm sensor_width gives a {fov:.4g}° field of view; "
            "it must be 0.1–179°",
            field,
        )
    return fov


class CameraKey(Section):
    """One key of the camera's path: its frame and the pose there (fov or focal_length: the camera's unless given)."""

    frame: Float = Field(description="Frame number of this key (fractional allowed).")
    position: Point3
    target: Point3
    fov: Fov | None = Field(None, description="Horizontal field of view, degrees (default: the camera's).")
    focal_length: FocalLength | None = Field(
        None,
        description="Focal length, mm, on the camera's sensor_width (an animated zoom): sets fov; not with fov.",
    )
    f_stop: FStop | None = Field(None, description="f-number at this key (a pulled aperture; default: the camera's).")
    focus_distance: FocusDistance | None = Field(
        None, description="Metres to the plane in focus at this key (a focus pull; default: the camera's)."
    )


class CameraConfig(Section):
    """A still camera, or a path through ``keys`` (centripetal Catmull–Rom), or one read from a USD stage (``usd``).

    The lens is either ``fov`` (horizontal, degrees) or ``focal_length`` (mm) on a ``sensor_width`` (mm, the
    filmback's horizontal aperture: USD ``horizontalAperture``, Maya's horizontal film aperture × 25.4); from
    the latter ``fov`` = 2·atan(sensor_width / (2·focal_length)) is derived here, so every backend reads ``fov``.

    Depth of field: ``f_stop`` N makes the camera a thin lens of radius r = f / (2N) (f the focal length in
    metres, given or derived from fov on sensor_width), focused at ``focus_distance`` metres along the view axis,
    or on the world point ``focus_on``, or — by default — on ``target`` (:mod:`forest.camera`).
    """

    position: Point3 | None = Field(
        None, description="Default: the first key, else a view over the terrain; with keys, the keys' poses are used."
    )
    target: Point3 | None = Field(None, description="Default: the first key's; with keys, the keys' targets are used.")
    fov: Fov = Field(40.0, description="Horizontal field of view, degrees (derived when focal_length is given).")
    focal_length: FocalLength | None = Field(
        None, description="Focal length, mm (e.g. 50): sets fov from sensor_width; give fov or focal_length, not both."
    )
    sensor_width: SensorWidth = Field(
        FULL_FRAME_MM,
        description="Filmback width (horizontal aperture), mm: 36 full frame, 24.89 Super 35, 36.7 ARRI Alexa LF.",
    )
    up: Vec3 = (0.0, 1.0, 0.0)
    f_stop: FStop | None = Field(
        None, description="Aperture as an f-number (e.g. 2.8): depth of field; default none, a pinhole (all sharp)."
    )
    focus_distance: FocusDistance | None = Field(
        None, description="Metres from the camera to the plane in focus, along the view axis (default: to target)."
    )
    focus_on: Point3 | None = Field(
        None,
        description="A world point to focus on (its distance along the view axis, every frame); not with "
        "focus_distance.",
    )
    keys: list[CameraKey] = Field(default_factory=list)
    usd: InputFile | None = Field(
        None,
        exclude=True,  # what it sets (pose, keys, lens) is in the dump; the file's own path would tie it to a folder
        description="A USD stage (.usda/.usdc/.usd) to take the camera from: its transform (animated: time "
        "samples become keys, frame = time code), focalLength, horizontalAperture and clippingRange; "
        "the stage's upAxis and metersPerUnit are converted to forest's Y up, metres.",
    )
    usd_camera: Annotated[Str, AfterValidator(_non_empty)] | None = Field(
        None, description="Prim path of the camera in usd (e.g. /World/cam); optional when the stage has one camera."
    )
    shutter: Unit = Field(0.0, description="Fraction of a frame the shutter is open (> 0: motion blur).")
    near: Positive = 0.5
    far: Positive = 100000.0
    fps: Positive = 24.0
    height_above_ground: Annotated[float, Field(ge=0.0, le=100000.0, allow_inf_nan=False)] | None = Field(
        None,
        description="Metres above the terrain under the camera (e.g. 1.7 for eye level): the height of position "
        "and of every key is taken from the ground there, their y ignored.",
    )

    @model_validator(mode="after")
    def _path(self, info: ValidationInfo) -> CameraConfig:
        given = set(self.model_fields_set)  # as written: what the usd camera sets below is not "given"
        if self.usd is not None:
            self._from_usd(info)
        elif self.usd_camera is not None:
            raise fail("names a camera prim, but usd (the stage) is not given", "usd_camera")
        frames = [k.frame for k in self.keys]
        if frames != sorted(frames) or len(set(frames)) != len(frames):
            raise fail("frames must be strictly increasing", "keys")
        if self.far <= self.near:
            raise fail(f"must be > near ({self.near:g})", "far")
        if math.hypot(*self.up) < 1e-9:
            raise fail("must not be the zero vector", "up")
        if self.focal_length is not None:
            if "fov" in given:
                raise fail(f"give fov or focal_length, not both (fov = {self.fov:g})", "focal_length")
            self.fov = _lens_fov(self.focal_length, self.sensor_width, "focal_length")
        for i, k in enumerate(self.keys):
            if k.focal_length is not None:
                if k.fov is not None:
                    raise fail(f"give fov or focal_length, not both (fov = {k.fov:g})", f"keys[{i}].focal_length")
                k.fov = _lens_fov(k.focal_length, self.sensor_width, f"keys[{i}].focal_length")
            elif k.fov is None:
                k.fov, k.focal_length = self.fov, self.focal_length
        self._lens()
        if self.keys:
            self.position = self.position or self.keys[0].position
            self.target = self.target or self.keys[0].target
        return self

    def _lens(self) -> None:
        """Refuse contradictory depth-of-field settings (ranges are the field types')."""
        if self.focus_on is not None and self.focus_distance is not None:
            raise fail("give focus_distance or focus_on, not both", "focus_on")
        for i, k in enumerate(self.keys):
            if k.f_stop is not None and self.f_stop is None:
                raise fail("animates the aperture of a pinhole camera; give [camera] f_stop too", f"keys[{i}].f_stop")
            if k.focus_distance is not None and self.focus_on is not None:
                raise fail("give focus_distance on keys or [camera] focus_on, not both", f"keys[{i}].focus_distance")

    def _from_usd(self, info: ValidationInfo) -> None:
        """Take pose, path and lens from the ``usd`` stage's camera (see :mod:`forest.usd_camera`)."""
        from ..usd_camera import USD_SETS, read_usd_camera

        assert self.usd is not None
        clash = sorted(USD_SETS & self.model_fields_set)
        if clash:
            raise fail(f"comes from the camera in usd ({self.usd.name}); remove it or remove usd", clash[0])
        if not (info.context or {}).get("check_files", True) and not self.usd.is_file():
            return  # validated again once its files are in place (the job service)
        try:
            shot = read_usd_camera(self.usd, self.usd_camera)
        except ForestError as e:
            raise fail(f"{self.usd.name}: {e.message}", e.field or "usd") from None
        self.position, self.target, self.up = shot.position, shot.target, shot.up
        self.focal_length, self.sensor_width, self.fov = shot.focal_length, shot.sensor_width, shot.fov
        try:
            self.keys = [CameraKey.model_validate(k) for k in shot.keys]
        except ValueError as e:  # a pose beyond the world's bounds
            raise fail(f"{self.usd.name}: a key out of range ({str(e).splitlines()[-1].strip()})", "usd") from None
        for name, value in (
            ("near", shot.near),
            ("far", shot.far),
            ("fps", shot.fps),
            ("shutter", shot.shutter),
            ("f_stop", shot.f_stop),
        ):
            if value is not None and name not in self.model_fields_set:
                setattr(self, name, value)

    def stand_on(self, height_at: Any) -> None:
        """With ``height_above_ground``: set the y of position and of every key to the terrain's ``height_at(x, z)``
        plus that height (in place; the same result however often it is called)."""
        h = self.height_above_ground
        if h is None:
            return

        def placed(p: tuple[float, float, float]) -> tuple[float, float, float]:
            y = float(height_at(float(p[0]), float(p[2]))[0])
            return (float(p[0]), y + float(h), float(p[2]))

        if self.position is not None:
            self.position = placed(self.position)
        for k in self.keys:
            k.position = placed(k.position)

    def resolve(self, terrain_size: tuple[float, float] | None, where: str = "camera.") -> None:
        """Fill a missing position/target with a view over the terrain and check the frame.

        Errors name ``where`` + the field (the scene-level validator calls this).
        """
        size = max(terrain_size) if terrain_size else 1000.0
        if self.position is None:
            self.position = (0.0, 0.15 * size, -0.6 * size)
        if self.target is None:
            self.target = (0.0, 0.0, 0.0)
        if self.position == self.target:
            raise fail("must differ from position", where + "target")
        d = [t - p for p, t in zip(self.position, self.target)]
        n = math.hypot(*d)
        u = self.up
        cross = (u[1] * d[2] - u[2] * d[1], u[2] * d[0] - u[0] * d[2], u[0] * d[1] - u[1] * d[0])
        if math.hypot(*cross) < 1e-6 * n * math.hypot(*u) and not self.keys:
            raise fail("is parallel to the view direction; give another up vector", where + "up")
        if self.focus_on is not None:
            poses = [(k.position, k.target) for k in self.keys] or [(self.position, self.target)]
            for p, t in poses:
                d = [b - a for a, b in zip(p, t)]
                ahead = sum((f - a) * c for a, f, c in zip(p, self.focus_on, d)) / max(math.hypot(*d), 1e-12)
                if ahead <= 0.0:
                    raise fail(
                        f"lies behind the camera at {tuple(p)} (depth {ahead:g} m); focus ahead", where + "focus_on"
                    )


# ---------------------------------------------------------------------------
# [lights]
# ---------------------------------------------------------------------------


class SunConfig(Section):
    """The sun: elevation, azimuth (clockwise from +Z, north, towards +X), and the irradiance and colour it sends."""

    elevation: Annotated[float, Field(ge=-90.0, le=90.0, allow_inf_nan=False)] = Field(
        35.0, description="Degrees above the horizon."
    )
    azimuth: Float = Field(120.0, description="Degrees, clockwise from +Z (north) towards +X (east).")
    irradiance: NonNegative = Field(3.0, description="W/m² on a surface facing the sun, per unit colour.")
    colour: RGB = Field((1.0, 0.95, 0.88), description="Linear RGB.")


class SunskyConfig(Section):
    """Mitsuba's Hosek–Wilkie sky and sun model (rotated to Y-up), pointed at the [lights.sun] direction.

    Its sun is scaled to send [lights.sun] irradiance (facing it) and its sky by the same factor,
    so the model's colours and sun-to-sky ratio are kept; ``scale`` multiplies both.
    """

    turbidity: Annotated[float, Field(ge=1.0, le=10.0, allow_inf_nan=False)] = 3.0
    albedo: Unit = Field(0.15, description="Ground albedo the sky model assumes.")
    scale: NonNegative = 1.0


def _hdri(value: Any) -> str:
    from ..hdri import SKIES

    if value not in SKIES:
        raise fail(f"unknown sky {value!r}; the shipped skies are {', '.join(SKIES)}")
    return str(value)


class SkyConfig(Section):
    """A constant sky (``radiance`` × ``colour``), an ``envmap``, a shipped ``hdri``, or ``sunsky``.

    An ``hdri`` is an environment map shipped with forest (``library/skies``).  With ``map_sun`` (the
    default for ``hdri``) the sun is found in the map, taken out of it and lights the scene as forest's
    disc sun in its direction, with its irradiance and colour (× ``scale``); a [lights.sun] wins over it.
    """

    radiance: NonNegative = Field(0.35, description="Constant sky: radiance.")
    colour: RGB = Field((0.6, 0.75, 1.0), description="Constant sky: linear RGB.")
    envmap: InputFile | None = Field(None, description="Latitude–longitude environment map (+Y up), EXR/HDR.")
    hdri: Annotated[Str, AfterValidator(_hdri)] | None = Field(
        None, description="A sky shipped with forest, by name: sunrise or sunset (library/skies)."
    )
    map_sun: Bool | None = Field(
        None,
        description="Environment map: find the sun in the map, take it out and light the scene with a disc sun "
        "matching it (default: true for hdri, false for envmap).",
    )
    scale: NonNegative = Field(1.0, description="Environment map: scale.")
    rotation: Annotated[float, Field(ge=-360.0, le=360.0, allow_inf_nan=False)] = Field(
        0.0,
        description="Environment map: turn it about the vertical, degrees; every azimuth in it (its sun's too) "
        "grows by this much.",
    )
    background: Literal["map", "sunsky"] = Field(
        "map",
        description="Environment map: what the camera sees where it sees the sky — the map itself, or (sunsky) "
        "forest's physical sky for the map's sun at the map's mean brightness, while the map still lights the "
        "scene (a photographed horizon no longer shows behind the terrain; forest_path only).",
    )
    sunsky: SunskyConfig | None = None

    @model_validator(mode="after")
    def _one_kind(self) -> SkyConfig:
        if sum(k is not None for k in (self.envmap, self.hdri, self.sunsky)) > 1:
            raise fail("give one of envmap, hdri or sunsky")
        given = self.model_fields_set
        if self.kind != "constant":
            for key in ("radiance", "colour"):
                if key in given:
                    raise fail("applies to a constant sky only", key)
        if self.kind != "envmap" and "scale" in given:
            raise fail("applies to an environment map only (sunsky has its own scale)", "scale")
        if self.kind != "envmap" and "rotation" in given:
            raise fail("applies to an environment map (envmap or hdri) only", "rotation")
        if self.kind != "envmap" and "map_sun" in given:
            raise fail("applies to an environment map (envmap or hdri) only", "map_sun")
        if self.kind != "envmap" and "background" in given:
            raise fail("applies to an environment map (envmap or hdri) only", "background")
        return self

    @property
    def splits_sun(self) -> bool:
        """Whether the map's sun is taken out and lights the scene as the disc sun (``map_sun``, by default
        for an ``hdri``)."""
        return self.kind == "envmap" and (self.map_sun if self.map_sun is not None else self.hdri is not None)

    @property
    def kind(self) -> str:
        """``"constant"``, ``"envmap"`` (a file or a shipped ``hdri``) or ``"sunsky"``."""
        if self.envmap is not None or self.hdri is not None:
            return "envmap"
        if self.sunsky is not None:
            return "sunsky"
        return "constant"


class CloudsConfig(Section):
    """A procedural cloud layer in the sky (forest_path; ``scalar_rgb`` renders the clear sky with a warning)."""

    cover: Unit = Field(0.4, description="Fraction of the sky covered, 0–1 (0: no clouds).")
    altitude: Annotated[float, Field(gt=0.0, le=100_000.0, allow_inf_nan=False)] = Field(
        2000.0, description="Height of the cloud layer, metres."
    )
    scale: Annotated[float, Field(gt=0.0, le=1.0e6, allow_inf_nan=False)] = Field(
        800.0, description="Size of the clouds, metres."
    )
    seed: Annotated[int, Strict(), Field(ge=0, le=2**31 - 1)] = Field(0, description="Pattern of the clouds.")
    density: Annotated[float, Field(gt=0.0, le=100.0, allow_inf_nan=False)] = Field(
        4.0, description="Optical thickness of a cloud's edge-to-core body (a core reaches about 3×)."
    )
    softness: Annotated[float, Field(gt=0.0, le=1.0, allow_inf_nan=False)] = Field(
        0.12, description="Width of the clouds' soft edges, in noise units (0.02 crisp – 0.3 wispy)."
    )
    wind: tuple[Metres, Metres] = Field((0.0, 0.0), description="Offset of the layer (x, z), metres.")
    height: Annotated[float, Field(ge=0.0, le=20_000.0, allow_inf_nan=False)] | None = Field(
        None,
        description="Height of the tallest cumulus above the layer, metres, as the camera sees them "
        "(default 0.4 × scale; 0: a flat layer).",
    )
    clustering: Unit = Field(
        0.5,
        description="How much the clouds gather into groups, about 6 × scale across, with clear sky between, "
        "and differ in height, 0–1 (0: evenly spread, all as tall).",
    )


class LightsConfig(Section):
    """``sun``, ``sky`` and ``clouds``; an empty or missing [lights] (or one with only ``clouds``) gives an
    outdoor daylight: the default sun (35° high, from the south-east) in Mitsuba's physical ``sunsky`` sky."""

    sun: SunConfig | None = None
    sky: SkyConfig | None = None
    clouds: CloudsConfig | None = None

    @model_validator(mode="before")
    @classmethod
    def _defaults(cls, data: Any) -> Any:
        if data is None or data == {}:
            return {"sun": {}, "sky": {"sunsky": {}}}
        if isinstance(data, dict) and set(data) == {"clouds"}:
            return {"sun": {}, "sky": {"sunsky": {}}, **data}
        return data

    @model_validator(mode="after")
    def _clouds_need_a_sky(self) -> LightsConfig:
        if self.clouds is not None and self.sky is None:
            raise fail("a cloud layer needs a sky ([lights.sky])", "clouds")
        if self.clouds is not None and self.sky is not None and (self.sky.envmap or self.sky.hdri):
            which = "hdri" if self.sky.hdri else "envmap"
            raise fail(
                f"a cloud layer draws over forest's own sky (sunsky or constant), not over an environment map "
                f"(lights.sky.{which}), whose photographed sky has its own clouds; remove one of them",
                "clouds",
            )
        return self


# ---------------------------------------------------------------------------
# [render], [lod], [wind]
# ---------------------------------------------------------------------------

Side = Annotated[Int, Field(ge=1, le=MAX_IMAGE_SIDE)]


def _view(value: Any) -> str:
    from ..imaging.view import check_view

    try:
        return check_view(value)
    except ForestError as e:
        raise fail(e.message) from None


def _look(value: Any) -> str:
    from ..imaging.view import check_look

    try:
        return check_look(value)  # the name alone; the model checks it against the view
    except ForestError as e:
        raise fail(e.message) from None


def _exposure(value: Any) -> float:
    from ..imaging.view import check_exposure

    try:
        return check_exposure(value)
    except ForestError as e:
        raise fail(e.message) from None


def _bool_or_auto(value: Any) -> bool | str:
    """A switch with a rule of its own: true, false or "auto" (``[render] denoise``:
    :func:`forest.imaging.denoise.denoise_rule`; ``haze_shafts``: on with a valley fog, ``forest.render.path.from_scene``)."""
    if isinstance(value, bool):
        return value
    if value == "auto":
        return "auto"
    raise fail(f'must be true, false or "auto", got {value!r}')


#: The comp AOVs ``[render] aovs`` may name (see docs/rendering.md, *Comp AOVs*). None is written by default:
#: N, P and albedo cost no render time (they come with the beauty's samples and the pixel-centre layers pass)
#: but double the EXR's size, which a farm writing thousands of frames pays for on every one; ask for them.
AOV_NAMES = ("N", "P", "albedo", "motion", "lightgroups")
DEFAULT_AOVS: tuple[str, ...] = ()


def _aovs(value: list[str]) -> list[str]:
    unknown = [v for v in value if v not in AOV_NAMES]
    if unknown:
        raise fail(f"unknown AOV {unknown[0]!r}; choose from {', '.join(AOV_NAMES)}")
    return sorted(set(value), key=AOV_NAMES.index)


class ValleyFog(Section):
    """``[render] valley_fog``: a fog that pools in low ground (forest.render.path.haze): extinction ``density``
    up to ``top``, thinning by e every ``falloff`` metres above it; the top rises and falls by up to
    ``variation`` metres in banks ``variation_scale`` metres across."""

    density: Positive = Field(description="Extinction per metre inside the fog (0.01: 390 m visibility).")
    top: Annotated[float, Field(ge=-100_000.0, le=100_000.0, allow_inf_nan=False)] = Field(
        20.0, description="Height of the fog's top, metres above the terrain's lowest point (or absolute)."
    )
    falloff: Annotated[float, Field(gt=0.0, le=100_000.0, allow_inf_nan=False)] = Field(
        15.0, description="Above the top the fog thins by e every this many metres."
    )
    absolute: Bool = Field(False, description="top is an absolute height (world Y), not above the lowest point.")
    variation: Annotated[float, Field(ge=0.0, le=100_000.0, allow_inf_nan=False)] = Field(
        6.0, description="How far the top rises and falls over the ground, metres: banks of fog (0: a level top)."
    )
    variation_scale: Annotated[float, Field(gt=0.0, le=1.0e6, allow_inf_nan=False)] = Field(
        150.0, description="Size of those banks, metres."
    )


class HorizonHillsConfig(Section):
    """Hills on the ground past the terrain's edge (``[render] horizon_hills``; :mod:`forest.skirt`, "Hills")."""

    height: Annotated[float, Field(ge=0.0, le=5000.0, allow_inf_nan=False)] = Field(
        150.0, description="Height of the highest hills above the far ground, metres (0: none)."
    )
    scale: Annotated[float, Field(ge=10.0, le=1.0e5, allow_inf_nan=False)] = Field(
        1500.0, description="Size of a hill, metres; the hills rise over this distance past the terrain's edge."
    )
    seed: Annotated[int, Strict(), Field(ge=0, le=2**31 - 1)] = Field(0, description="Pattern of the hills.")
    erosion: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] | None = Field(
        None,
        description="Gullies and spurs down the hills' slopes, 0-1 (their depth; 0: smooth hills; default: from "
        "the height, none up to 300 m, full from 1200 m, so that mountains are eroded and rolling hills smooth).",
    )
    woods: Bool = Field(
        True,
        description="forest_path: woods and open ground in patches on that far ground, in the terrain's own "
        "canopy cover, colours and canopy height, the woods' crowns on the skyline (false: one colour, smooth "
        "hills).",
    )
    treeline: Float | None = Field(
        None, description="forest_path: height (world Y, metres) above which those woods give way to open ground."
    )
    rockline: Float | None = Field(
        None, description="forest_path: height (world Y, metres) above which the open ground is [ground]'s rock."
    )
    snowline: Float | None = Field(
        None,
        description="forest_path: height (world Y, metres) above which the land lies under [ground]'s snow "
        "(faces steeper than about 50 degrees stay bare).",
    )

    @model_validator(mode="after")
    def _lines(self) -> HorizonHillsConfig:
        if self.treeline is not None and self.rockline is not None and self.rockline < self.treeline:
            raise fail("must not be below treeline", "rockline")
        return self


class RenderConfig(Section):
    """The image (size, samples, variant), light paths, aerial haze, the ground's look and the PNG's view transform."""

    width: Side = Field(1280, description="Pixels.")
    height: Side = Field(720, description="Pixels.")
    spp: Annotated[Int, Field(ge=1, le=65536)] = Field(64, description="Samples per pixel.")
    variant: Literal["scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb"] | None = Field(
        None, description="Mitsuba variant (default: chosen per machine and scene)."
    )
    max_depth: Annotated[Int, Field(ge=1, le=64)] = Field(6, description="Longest light path, in bounces + 1.")
    subframes: Annotated[Int, Field(ge=1, le=64)] = Field(5, description="Sub-frames averaged for motion blur.")
    haze: NonNegative = Field(0.0, description="Aerial perspective: extinction per metre at the ground.")
    visibility: Annotated[float, Field(gt=0.0, le=10_000.0, allow_inf_nan=False)] | None = Field(
        None,
        description="Aerial perspective as a visibility, km (Koschmieder: haze = 3.912 / V per km); "
        "instead of haze, not with it.",
    )
    haze_height: Annotated[float, Field(gt=0.0, le=100_000.0, allow_inf_nan=False)] = Field(
        150.0, description="Aerial perspective: height over which the haze thins by e (scale height), metres."
    )
    valley_fog: ValleyFog | None = Field(
        None,
        description="A fog that pools in low ground: { density, top, falloff, absolute, variation, "
        "variation_scale } (default none).",
    )
    haze_colour: RGB | None = Field(
        None, description="Radiance the haze tends to away from the sun (default: the sky's mean radiance)."
    )
    haze_anisotropy: Annotated[float, Field(ge=-0.95, le=0.95, allow_inf_nan=False)] = Field(
        0.7, description="Henyey-Greenstein g of the haze: > 0 glows toward the sun, 0 scatters evenly."
    )
    haze_shafts: Annotated[Any, AfterValidator(_bool_or_auto)] = Field(
        "auto",
        description="forest_path: the sun lights the haze and valley fog only where nothing stands between them "
        "(light shafts through crowns, the clouds' shadows on the haze; one more shadow ray per camera ray, +13-21 %): true, false (the haze lit "
        'everywhere) or "auto": on with a valley_fog, where they show (docs/rendering.md, Light shafts).',
    )
    terrain_colour: RGB = Field(
        (0.18, 0.16, 0.11), description="Given: the ground is this one material (linear RGB) instead of [ground]."
    )
    terrain_texture: InputFile | None = Field(
        None, description="Image laid over the extent (map convention); overrides terrain_colour and [ground]."
    )
    horizon_ground: Bool = Field(
        True, description="The ground runs on past the terrain's edge to the horizon (a skirt at its edge height)."
    )
    horizon_hills: HorizonHillsConfig | None = Field(
        None,
        description="Hills on that ground (height, scale, seed, metres): hazed silhouettes toward the horizon "
        "instead of a level plain; off by default. Drawn by forest's renderers; the exports write the hills in one far colour (no woods, rock or snow).",
    )
    seed: Annotated[Int, Field(ge=0)] = Field(0, description="Sampler seed.")
    alpha_shadows: Bool = Field(
        True, description="scalar_rgb: shadow rays see through leaf-card alpha (forest_path always does)."
    )
    denoise: Annotated[Any, AfterValidator(_bool_or_auto)] = Field(
        False,
        description="Denoise every frame with Open Image Denoise, guided by the first-hit albedo and normal "
        "(--preview always does): true (needs the 'denoise' extra, pyoidn), false, or \"auto\": when pyoidn is "
        "installed and spp <= 16, where it measurably pays (docs/rendering.md, Denoising).",
    )
    view: Annotated[str, AfterValidator(_view)] = Field(
        "agx",
        description="View transform of the PNG: agx, filmic, standard or aces (the EXR stays scene-linear).",
    )
    exposure: Annotated[Any, AfterValidator(_exposure)] = Field(
        0.0, description="Exposure of the PNG, EV (stops), -10 to 10.", json_schema_extra={"type": "number"}
    )
    look: Annotated[str, AfterValidator(_look)] = Field(
        "none",
        description="A grade of the agx view's PNG, one of Blender's AgX looks: none, punchy (deeper, more "
        "chroma: a bright blue sky stays blue), or very_high / high / medium_high / medium_low / low / "
        "very_low_contrast (the EXR stays scene-linear).",
    )
    working_space: Literal["rec709", "acescg"] = Field(
        "rec709",
        description="Colour space of the EXR's beauty and colour layers: rec709 (linear Rec.709, as rendered) or "
        "acescg (linear ACES AP1, converted; the header says which). The PNG is the same in both.",
    )
    aovs: Annotated[list[str], AfterValidator(_aovs)] = Field(
        list(DEFAULT_AOVS),
        description="Comp layers written beside the beauty: N (first-hit normal), P (world position), albedo, "
        "motion (screen-space vectors, forward.u/v) and lightgroups (sun, sky, haze; forest_path only).",
        json_schema_extra={"items": {"enum": list(AOV_NAMES)}, "uniqueItems": True},
    )
    noise_threshold: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = Field(
        0.0,
        description="Adaptive sampling (forest_path): a pixel stops once the relative standard error of its mean "
        "luminance is below this (e.g. 0.01-0.05); 0 traces spp everywhere. scalar_rgb ignores it.",
    )
    min_spp: Annotated[Int, Field(ge=1, le=65536)] | None = Field(
        None,
        description="Adaptive sampling: samples every pixel takes before it may stop, and per pass after "
        "(default max(16, spp/8), at most spp).",
    )

    @model_validator(mode="after")
    def _visibility(self) -> RenderConfig:
        if self.visibility is not None:
            if "haze" in self.model_fields_set:
                raise fail("give haze or visibility, not both", "visibility")
            self.haze = 3.912 / (1000.0 * self.visibility)  # Koschmieder (forest.render.path.haze)
        return self

    @model_validator(mode="after")
    def _look_on_agx(self) -> RenderConfig:
        if self.look != "none" and self.view != "agx":
            raise fail(f'look {self.look!r} grades the agx view; the view is {self.view!r} (use view = "agx")', "look")
        return self

    @model_validator(mode="after")
    def _hills_need_the_ground(self) -> RenderConfig:
        if self.horizon_hills is not None and not self.horizon_ground:
            raise fail(
                "hills stand on the ground past the terrain's edge: needs horizon_ground = true", "horizon_hills"
            )
        return self

    @model_validator(mode="after")
    def _adaptive(self) -> RenderConfig:
        if self.min_spp is not None and self.min_spp > self.spp:
            raise fail(f"must be at most spp ({self.spp}), got {self.min_spp}", "min_spp")
        return self


#: ``[lod] pixels`` when none are given: thresholds of a tree's projected height, pixels, high → medium → low → far.
#: With the library's budgets (high ≤ 70 000 triangles, medium ~12 000, low ~1 500, far 6) each level is used
#: where it spends very roughly 0.3–3 triangles per pixel the tree covers, and the far level's crossed cards
#: (a 128-pixel impostor per view) only where the whole tree is under 20 pixels tall.
DEFAULT_LOD_PIXELS = (240.0, 80.0, 20.0)


class LodConfig(Section):
    """Level of detail per tree: by its projected size in pixels (automatic, the default), by camera distance
    (``distances``), or off (``auto = false``: every tree at its highest level)."""

    distances: (
        Annotated[list[Positive], Field(min_length=1, max_length=3, json_schema_extra={"uniqueItems": True})] | None
    ) = Field(
        None,
        description="Manual boundaries high → medium → low → far, metres from the camera, the same for every "
        "species and tree size; given, they replace the automatic rule.",
    )
    pixels: (
        Annotated[list[Positive], Field(min_length=1, max_length=3, json_schema_extra={"uniqueItems": True})] | None
    ) = Field(
        None,
        description="Automatic rule: thresholds of a tree's projected height in pixels (its species' highest "
        "level's bound height × its scale, at its camera distance, for [render] width and the camera's fov), "
        "strictly decreasing, high → medium → low → far (default [240, 80, 20]).",
    )
    auto: Bool = Field(
        True,
        description="Without distances: choose each tree's level by its projected size (pixels); "
        "false turns level of detail off, every tree at its highest level.",
    )
    solid_pixels: NonNegative = Field(
        80.0,
        description="The forest renderer draws the cut-out leaf cards of a tree at most this many pixels tall "
        "(its projected height, as the automatic rule measures it) and below its highest level as opaque cards of the same covered area, each "
        "triangle shrunk to its alpha coverage: no ray restarts past their gaps, the same picture where a card is "
        "about a pixel (1.5x faster on the 130 000-tree case study). 0 keeps every card cut out.",
    )

    @field_validator("distances")
    @classmethod
    def _increasing(cls, v: list[float] | None) -> list[float] | None:
        if v is not None and list(v) != sorted(set(v)):
            raise fail(f"must be positive and strictly increasing, got {list(v)}")
        return v

    @field_validator("pixels")
    @classmethod
    def _decreasing(cls, v: list[float] | None) -> list[float] | None:
        if v is not None and list(v) != sorted(set(v), reverse=True):
            raise fail(f"must be positive and strictly decreasing, got {list(v)}")
        return v

    @model_validator(mode="after")
    def _one_rule(self) -> LodConfig:
        if self.pixels is not None and self.distances is not None:
            raise fail("give distances (manual) or pixels (automatic), not both", "pixels")
        if self.pixels is not None and not self.auto:
            raise fail("apply to the automatic rule, which auto = false turns off; remove one of them", "pixels")
        return self

    @property
    def mode(self) -> Literal["distances", "pixels", "off"]:
        """Which rule chooses the levels: ``distances``, ``pixels`` (automatic) or ``off``."""
        if self.distances is not None:
            return "distances"
        return "pixels" if self.auto else "off"

    @property
    def enabled(self) -> bool:
        """Whether trees change level at all (``auto = false`` without distances turns it off)."""
        return self.mode != "off"

    @property
    def bands(self) -> tuple[float, ...]:
        """The manual distance boundaries as a tuple (empty unless ``distances`` is given)."""
        return tuple(self.distances or ())

    @property
    def thresholds(self) -> tuple[float, ...]:
        """The automatic rule's pixel thresholds (:data:`DEFAULT_LOD_PIXELS` unless given; empty in the other modes)."""
        if self.mode != "pixels":
            return ()
        return tuple(self.pixels) if self.pixels is not None else DEFAULT_LOD_PIXELS


class WindConfig(Section):
    """Wind sway of the trees over time: amplitude, frequency and direction."""

    strength: Annotated[float, Field(ge=0.0, le=45.0, allow_inf_nan=False)] = Field(
        0.0, description="Sway amplitude, degrees."
    )
    frequency: NonNegative = Field(0.4, description="Sways per second.")
    direction: Float = Field(0.0, description="Degrees, same convention as the sun's azimuth.")


# ---------------------------------------------------------------------------
# [lookdev], [export]
# ---------------------------------------------------------------------------

LOOKDEV_PARAMS = ("camera", "sun", "sky", "leaves", "ground", "haze", "colour_map")


class LookdevConfig(Section):
    """Defaults of ``forest match``'s options, and the per-species leaf tints a fit writes."""

    iterations: Annotated[Int, Field(ge=1, le=100)] = Field(
        8, description="Gauss–Newton iterations (each: a few renders, then an exact step on the surrogate)."
    )
    resolution: Annotated[Int, Field(ge=16, le=1024)] = Field(
        96, description="Long side of the fit's renders, pixels (the reference is resampled to it)."
    )
    spp: Annotated[Int, Field(ge=1, le=1024)] = Field(16, description="Samples per pixel of the fit's renders.")
    params: (
        Annotated[list[Literal["camera", "sun", "sky", "leaves", "ground", "haze", "colour_map"]], Field(min_length=1)]
        | None
    ) = Field(
        None,
        description="Parameter groups to fit (default: all; colour_map only in aligned mode).",
    )
    mode: Literal["aligned", "statistics"] = Field(
        "aligned", description="aligned: a plate from the same camera; statistics: an unrelated photo."
    )
    grid: Annotated[Int, Field(ge=1, le=64)] | Literal["auto"] = Field(
        "auto",
        description="Colour-map cells per side the fit varies (1 to 64), or 'auto': the finest grid whose cells that "
        "hold trees have on average at least 24 canopy pixels in the fit's render.",
    )
    map_prior: Literal["edges", "smooth"] = Field(
        "edges",
        description="The colour map's prior: 'edges' (cells a painted pattern can be recovered into, an edge costs its "
        "height) or 'smooth' (a smooth correction of the painted map).",
    )
    anchor: Literal["auto", "ground", "leaves", "lights", "none"] = Field(
        "auto",
        description="What holds the scale of albedos against light: the ground's albedo, the leaves', the lights' "
        "level, or none (the priors); auto: ground in aligned mode when the frame shows ground (else leaves), none "
        "in statistics mode.",
    )
    fresh_map: Bool = Field(False, description="Fit a new grid×grid colour map instead of correcting the painted one.")
    mask: InputFile | None = Field(
        None,
        description="Regions painted over the reference: sky #0000ff, canopy #00ff00, ground #ff0000, "
        "ignored #000000, automatic #ffffff.",
    )
    fit: Literal["crop", "stretch"] = Field("crop", description="How a reference of another aspect ratio is fitted.")
    variant: Literal["llvm_ad_rgb", "cuda_ad_rgb"] | None = None
    report_width: Annotated[Int, Field(ge=64, le=2048)] = Field(384, description="Width of the report's renders.")
    leaf_tint: dict[Str, RGB] | None = Field(
        None,
        description="Multiplier of each species' leaf colour, by species name or model (written by forest match; "
        "the forest path tracer renders it).",
    )
    ground_tint: RGB | None = Field(
        None,
        description="Multiplier of the ground's albedo, whatever makes it (written by forest match; "
        "the forest path tracer renders it).",
    )


class ExportConfig(Section):
    """How ``forest export`` writes: RIB level cross-fades, display and textures; the USD and Blender levels."""

    lod_transition: Annotated[float, Field(ge=0.0, le=0.9, allow_inf_nan=False)] = Field(
        0.1, description="Fraction of a LOD distance over which RIB levels cross-fade."
    )
    rib_lod: Literal["inline", "archive"] = Field("inline", description="Where RIB's Detail/DetailRange go.")
    usd_lod: Str | None = Field(None, description="The `lod` variant USD prototypes select.")
    rib_display: Literal["file", "tiff", "openexr", "exr", "png", "framebuffer", "it"] = Field(
        "file",
        description="RIB Display driver: 'file' and 'framebuffer' every RenderMan-compliant renderer has "
        "('file' writes a TIFF); 'tiff', 'openexr', 'it' PRMan / RenderMan 22+; 'exr' Aqsis, 3Delight; "
        "'png' RenderMan 22+.",
    )
    rib_textures: Literal["tif", "tex"] | None = Field(
        None,
        description="Texture files the RIB names: 'tif' (read by RI 3.2 renderers as written) or 'tex' "
        "(made from the TIFFs by prepare.sh with txmake, tdlmake, teqser or texmake). "
        "Default 'tif', 'tex' with --renderman22.",
    )
    blender_lod: Str | None = Field(None, description="The level Blender instances (default each species' first).")


# ---------------------------------------------------------------------------
# The scene file
# ---------------------------------------------------------------------------


class SceneConfig(Section):
    """A forest scene file."""

    model_config = ConfigDict(title="forest scene", json_schema_extra={"$comment": "forest schema"})

    seed: Annotated[Int, Field(ge=0, le=2**63 - 1)] = Field(0, description="Seed of every random choice.")
    name: Annotated[Str, Field(min_length=1)] | None = Field(None, description="Default: the file's name.")
    terrain: TerrainConfig
    maps: MapsConfig = Field(default_factory=MapsConfig)
    partitions: PartitionsConfig = Field(default_factory=PartitionsConfig)
    scatter: ScatterConfig = Field(default_factory=ScatterConfig)
    species: Annotated[list[SpeciesConfig], Field(min_length=1)]
    ecosystem: EcosystemConfig = Field(default_factory=EcosystemConfig)
    ground: GroundConfig = Field(default_factory=GroundConfig)
    ground_cover: list[GroundCoverConfig] = Field(default_factory=list)
    tree: Annotated[list[PlacedTree], Field(max_length=MAX_PLACED_TREES)] = Field(
        default_factory=list, description="Trees placed by hand, each one of a [[species]]' trees."
    )
    camera: CameraConfig = Field(default_factory=CameraConfig)
    lights: LightsConfig = Field(default_factory=lambda: LightsConfig.model_validate({}))
    render: RenderConfig = Field(default_factory=RenderConfig)
    lod: LodConfig = Field(default_factory=LodConfig)
    wind: WindConfig = Field(default_factory=WindConfig)
    lookdev: LookdevConfig = Field(default_factory=LookdevConfig)
    export: ExportConfig = Field(default_factory=ExportConfig)

    @model_validator(mode="after")
    def _across_sections(self) -> SceneConfig:
        total = sum(s.percent for s in self.species)
        if total > 100.0 + 1e-9:
            raise fail(f"percentages add up to {total:g}, more than 100", "species")
        labels = self.partitions.labels
        if labels and self.maps.partition is None:
            raise fail("regions are given but [maps] partition is not", "partitions")
        if self.maps.partition is not None and not labels:
            raise fail("[maps] partition is given but no [partitions] label colours", "partitions")
        known = [n for _, n in labels] + (["unlabelled"] if labels else [])
        for i, sp in enumerate(self.species):
            for region in sp.partitions or ():
                if region not in known:
                    raise fail(
                        f"unknown region {region!r} (regions: {', '.join(known) or 'none'})", f"species[{i}].partitions"
                    )
        for i, tree in enumerate(self.tree):
            try:
                k = species_index(self.species, tree.species)
            except ValueError as e:
                raise fail(str(e), f"tree[{i}].species") from None
            count = self.species[k].individual_count
            if tree.dead and count > MAX_INDIVIDUALS // 2:
                raise fail(
                    f"needs species[{k}]'s individuals <= {MAX_INDIVIDUALS // 2} (snags take the upper half)",
                    f"tree[{i}].dead",
                )
            if tree.individual is not None and tree.individual >= count:
                raise fail(
                    f"must be below species[{k}]'s {count} individual{'s' if count > 1 else ''}, got {tree.individual}",
                    f"tree[{i}].individual",
                )
        ground_given = {"rules", "base", "materials"} & self.ground.model_fields_set
        if "terrain_colour" in self.render.model_fields_set and ground_given:
            raise fail(
                f"is one ground colour, but [ground] gives {', '.join(sorted(ground_given))}; remove one of them",
                "render.terrain_colour",
            )
        if self.terrain.procedural is not None and self.terrain.procedural.seed is None:
            self.terrain.procedural.seed = self.seed
        self.camera.resolve(self.terrain.extent_size)
        return self


def file_fields(model: type[BaseModel] = SceneConfig, prefix: str = "") -> list[str]:
    """Dotted names of every field that names an input file (``[]`` marks a list of tables).

    Derived from the :class:`FileRef` markers of the schema, so the service's
    asset handling, look-dev's rebasing and ``forest examples`` agree on which
    strings are paths.  (``species[].model`` also names a file when it has a
    mesh suffix: see :attr:`SpeciesConfig.is_mesh`.)
    """
    out: list[str] = []
    for name, field in model.model_fields.items():
        dotted = f"{prefix}{name}"
        annotation = field.annotation
        if _is_file(annotation) or any(isinstance(m, FileRef) for m in field.metadata):
            out.append(dotted)
            continue
        for t, in_list in _model_types(annotation):
            out.extend(file_fields(t, dotted + ("[]." if in_list else ".")))
    return out


def _is_file(annotation: Any) -> bool:
    if typing.get_origin(annotation) is Annotated:
        return any(isinstance(m, FileRef) for m in typing.get_args(annotation)[1:])
    return any(_is_file(a) for a in typing.get_args(annotation) if typing.get_origin(annotation) is not list)


def _model_types(annotation: Any, in_list: bool = False) -> list[tuple[type[BaseModel], bool]]:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [(annotation, in_list)]
    out = []
    inner_list = in_list or typing.get_origin(annotation) is list
    for a in typing.get_args(annotation):
        if a is not type(None):
            out.extend(_model_types(a, inner_list))
    return out
