"""Building recipes: the ``[building]`` table's keys, their defaults and their validation.

A preset with ``kind = "building"`` holds one ``[building]`` table.  Keys common
to every type are in :data:`COMMON`, the keys of one type in :data:`SPECIFIC`;
ranges are ``[lo, hi]`` drawn per seed (``lo + (hi − lo)·U``), colours are
lists of linear RGB triples one of which each seed picks.  :func:`validate_recipe`
fills the defaults and names the file and the field of the first bad key.
"""

from __future__ import annotations

import math
from typing import Any

from ...errors import ConfigError

TAG = 0xB01D  # RNG stream tag of the building generator
TYPES = ("tower", "apartment", "house", "warehouse")
LODS = ("high", "medium", "low", "far")
BUDGETS = {
    "tower": {"high": (500, 8000), "medium": (100, 1500), "low": (20, 300), "far": (10, 10)},
    "apartment": {"high": (300, 8000), "medium": (100, 1500), "low": (20, 300), "far": (10, 10)},
    "house": {"high": (150, 2000), "medium": (30, 400), "low": (19, 100), "far": (10, 18)},
    "warehouse": {"high": (200, 4000), "medium": (40, 800), "low": (14, 200), "far": (10, 10)},
}

# Common keys and their defaults; ranges are [lo, hi] drawn per seed.
COMMON: dict[str, Any] = {
    "type": None,
    "width": [20.0, 30.0],
    "depth": [15.0, 25.0],
    "floors": [2, 4],
    "floor_height": 3.0,
    "bay": 3.0,
    "wall_colours": [[0.5, 0.5, 0.5]],
    "roof_colours": [[0.2, 0.2, 0.2]],
    "trim_colour": [0.3, 0.3, 0.3],
    "tint_roof": True,
    "tint_walls": False,
    "parapet": 1.0,
}
SPECIFIC: dict[str, dict[str, Any]] = {
    "tower": {"setbacks": [1, 3], "setback": [2.0, 4.5], "fin_depth": 0.45, "spire_chance": 0.3},
    "apartment": {"balcony_depth": 1.4, "balcony_every": 2},
    "house": {"pitch": [28.0, 42.0], "overhang": 0.45},
    "warehouse": {"roof": "sawtooth", "tooth": [7.0, 10.0], "tooth_rise": [2.0, 3.0], "doors": [2, 5]},
}


def _num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def validate_recipe(recipe: dict, where: str = "recipe") -> dict:
    """Fill defaults and check a building recipe; raise :class:`ConfigError` naming the bad field."""
    if not isinstance(recipe, dict) or not isinstance(recipe.get("building"), dict):
        raise ConfigError(where, "building", "a building preset needs a [building] table")
    b_in = recipe["building"]
    btype = b_in.get("type")
    if btype not in TYPES:
        raise ConfigError(where, "building.type", f"must be one of {', '.join(TYPES)}, got {btype!r}")
    known: dict[str, Any] = dict(COMMON)
    known.update(SPECIFIC[btype])
    unknown = sorted(set(b_in) - set(known))
    if unknown:
        raise ConfigError(
            where, f"building.{unknown[0]}", f"unknown key for a {btype} (expected one of: {', '.join(sorted(known))})"
        )
    b: dict[str, Any] = dict(known)
    b.update(b_in)
    ints = {"floors", "setbacks", "balcony_every", "doors"}
    for key, default in known.items():
        v = b[key]
        f = f"building.{key}"
        if isinstance(default, list) and default and _num(default[0]):  # a [lo, hi] range or an RGB
            if key == "trim_colour":
                if not (isinstance(v, list) and len(v) == 3 and all(_num(x) and 0 <= x <= 1 for x in v)):
                    raise ConfigError(where, f, f"must be three numbers in [0, 1], got {v!r}")
                continue
            if not (isinstance(v, list) and len(v) == 2 and all(_num(x) for x in v) and 0 <= v[0] <= v[1]):
                raise ConfigError(where, f, f"must be a range [lo, hi] with 0 <= lo <= hi, got {v!r}")
            if key in ints and not all(float(x).is_integer() for x in v):
                raise ConfigError(where, f, f"must be whole numbers, got {v!r}")
            if key in ("width", "depth") and not (v[0] >= 1.0 and v[1] <= 500.0):
                raise ConfigError(where, f, f"must lie in [1, 500] metres, got {v!r}")
            if key == "floors" and not (v[0] >= 1 and v[1] <= 200):
                raise ConfigError(where, f, f"must lie in [1, 200], got {v!r}")
            if key == "pitch" and not (v[0] >= 5 and v[1] < 75):
                raise ConfigError(where, f, f"must lie in [5, 75) degrees, got {v!r}")
        elif isinstance(default, list):  # colour lists
            if not (
                isinstance(v, list)
                and v
                and all(isinstance(c, list) and len(c) == 3 and all(_num(x) and 0 <= x <= 1 for x in c) for c in v)
            ):
                raise ConfigError(where, f, f"must be a list of RGB triples in [0, 1], got {v!r}")
        elif isinstance(default, bool):
            if not isinstance(v, bool):
                raise ConfigError(where, f, f"must be true or false, got {v!r}")
        elif key == "roof":
            if v not in ("sawtooth", "flat"):
                raise ConfigError(where, f, f"must be sawtooth or flat, got {v!r}")
        elif key in ints:
            if not (isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 100):
                raise ConfigError(where, f, f"must be a whole number in [1, 100], got {v!r}")
        elif default is not None and (
            not (_num(v) and v >= 0) or (key in ("floor_height", "bay") and not 0.5 <= v <= 50)
        ):
            raise ConfigError(where, f, f"must be a number >= 0 (floor_height, bay: 0.5 to 50), got {v!r}")
    if btype == "tower" and not 0 <= b["spire_chance"] <= 1:
        raise ConfigError(where, "building.spire_chance", f"must be in [0, 1], got {b['spire_chance']!r}")
    return {"kind": "building", "building": b}
