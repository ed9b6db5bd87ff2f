"""The species an InstanceSet holds: the ``[[species]]`` models, then the ``[[ground_cover]]`` ones.

Trees and ground cover are rows of one InstanceSet, so every backend (render,
RIB, USD, look-dev) draws both without knowing the difference.  Species index
``s`` of the set is ``[[species]][s]`` for ``s < len(species)`` and
``[[ground_cover]][s − len(species)]`` after that; ``species_names`` lists
their ``model`` strings in that order (:func:`scatter_models`).  Each entry has
its own look settings (``individuals``, ``colour_jitter``), read through
:func:`model_settings`, and a config field that names it in messages
(:func:`model_field`).
"""

from __future__ import annotations

import re

from ..config import Config
from ..config.schema import GroundCoverConfig, SpeciesConfig
from ..errors import ConfigError, ForestError
from ..library import Library, Species
from ..library.individuals import individual_seed
from .canopy import has_leaves, snag
from .placed import placed_species


def model_settings(config: Config) -> list[SpeciesConfig | GroundCoverConfig]:
    """The settings of every species index of the scene's InstanceSet: ``[[species]]`` then ``[[ground_cover]]``."""
    return [*config.species, *config.model.ground_cover]


def scatter_models(config: Config) -> list[str]:
    """The ``species_names`` a scatter of ``config`` writes: every ``[[species]]`` then ``[[ground_cover]]`` model."""
    return [s.model for s in model_settings(config)]


def model_field(config: Config, index: int) -> str:
    """The config field naming species index ``index``: ``species[i].model`` or ``ground_cover[j].model``."""
    n = len(config.species)
    return f"species[{index}].model" if index < n else f"ground_cover[{index - n}].model"


def resolve_models(config: Config, library: Library) -> tuple[Species, ...]:
    """The library species of every model of :func:`scatter_models`; a failure names its field."""
    out = []
    for i, model in enumerate(scatter_models(config)):
        field = model_field(config, i)
        try:
            sp = library.resolve(model, config.base_dir)
        except ForestError as e:
            raise ConfigError(config.path, field, e.message) from None
        except (OSError, KeyError, ValueError) as e:
            raise ConfigError(config.path, field, f"cannot resolve tree model {model!r}: {e}") from None
        if not sp.lods:
            raise ConfigError(config.path, field, f"tree model {model!r} has no levels of detail")
        out.append(sp)
    return tuple(out)


def model_individuals(
    library: Library, model: str, first: Species, count: int, field: str, config: Config
) -> tuple[Species, ...]:
    """Individuals ``0 … count − 1`` of ``model`` (``first`` is individual 0, already resolved).

    A generated library species ``NAME`` (manifest seed b) or ``NAME@b`` has
    individual k = the recipe grown with seed b + k
    (:func:`forest.library.individual`); an imported species or a mesh file has
    one individual, whatever ``count`` says (as has every species of a
    library object that is not a :class:`~forest.library.Library`, which
    cannot grow them).
    """
    m = re.fullmatch(r"(.+)@(\d+)", model)
    name = m.group(1) if m else model
    grows = isinstance(library, Library) and getattr(first, "source", None) == "generated"
    if count <= 1 or not grows or name not in library.names():
        return (first,)
    try:
        base = int(m.group(2)) if m else individual_seed(library, name, 0)
        if base is None:
            return (first,)
        rest = tuple(library.get(name, seed=base + k) for k in range(1, count))
    except ForestError as e:
        raise ConfigError(config.path, field, e.message) from None
    return (first, *rest)


def resolve_individuals(
    config: Config, library: Library, species: tuple[Species, ...]
) -> tuple[tuple[Species, ...], ...]:
    """Per species index, its individuals (element 0 is ``species[s]``); see :func:`model_individuals`.

    A ``[[species]]`` with ``dead`` > 0, or one a ``[[tree]]`` with ``dead = true`` is of, and leaf parts has
    its n individuals followed by their n snags (:func:`forest.scatter.canopy.snag`): a snag's ``individual``
    is n + k.
    """
    settings = model_settings(config)
    placed_dead = {int(k) for t, k in zip(config.model.tree, placed_species(config)) if t.dead}
    out = []
    for i, s in enumerate(settings):
        ind = model_individuals(library, s.model, species[i], s.individual_count, model_field(config, i), config)
        if (getattr(s, "dead", 0.0) > 0 or i in placed_dead) and has_leaves(species[i]):
            alive = tuple(ind[k % len(ind)] for k in range(s.individual_count))  # as many as scatter drew from
            ind = alive + tuple(snag(sp) for sp in alive)
        out.append(ind)
    return tuple(out)
