"""Several individuals per species: the ``k``-th individual of a generated species, deterministically.

A generated species is a recipe plus a seed (the manifest's ``seed``, the
*base* seed).  Its ``k``-th individual is the same recipe grown with seed
``base + k`` — exactly the species a scene names ``"NAME@(base + k)"`` — so
individual 0 is the species itself and every individual is built once into
the library's cache under its own content hash.  The seed draws the
individual's height, crown width, branch angles, crown base and lean
(:func:`forest.library.generator.grow`) as well as every branch and leaf, so
individuals of one species are visibly different trees of the same kind.

Imported species have one individual (their mesh): every ``k`` gives it.

```python
from forest.library import individual, individuals, open_library
lib = open_library()
oak_3 = individual(lib, "broadleaf", 3)       # = lib.resolve("broadleaf@<seed + 3>")
row = individuals(lib, "conifer", 4)          # individuals 0..3, built if needed
```
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..errors import ForestError

if TYPE_CHECKING:
    from .core import Library, Species

MAX_INDIVIDUALS = 4096


def individual_seed(lib: Library, name: str, k: int) -> int | None:
    """The seed of individual ``k`` of ``name`` (``base + k``), or None for an imported species."""
    if isinstance(k, bool) or not isinstance(k, int) or not 0 <= k < MAX_INDIVIDUALS:
        raise ForestError(f"individual of {name!r} must be a whole number in [0, {MAX_INDIVIDUALS}), got {k!r}")
    if lib.entry(name).get("source", "generated") != "generated":
        return None
    _, base = lib.recipe(name)
    return base + k


def individual(lib: Library, name: str, k: int, *, build: bool = True) -> Species:
    """Individual ``k`` of species ``name``: the recipe grown with the manifest's seed + ``k``.

    ``k = 0`` is the species itself (the same cache folder as ``lib.get(name)``);
    ``k > 0`` is the species ``"NAME@(seed + k)"``.  Deterministic: the same
    library, name and ``k`` give the same files.  Imported species return
    their one mesh for every ``k``.
    """
    seed = individual_seed(lib, name, k)
    if seed is None or k == 0:
        return lib.get(name, build=build)
    return lib.get(name, seed=seed, build=build)


def individuals(lib: Library, name: str, count: int, *, build: bool = True) -> list[Species]:
    """Individuals ``0 … count − 1`` of ``name`` (see :func:`individual`)."""
    if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= MAX_INDIVIDUALS:
        raise ForestError(f"individuals of {name!r}: count must be a whole number in [1, {MAX_INDIVIDUALS}]")
    return [individual(lib, name, k, build=build) for k in range(count)]
