"""The scatter pipeline: terrain and maps → shared candidate stages → a survival rule → an InstanceSet.

:func:`scatter` runs, in order:

1. :func:`~forest.scatter.candidates.candidates` — ``count`` sites by surface
   area and the rules every method obeys (presence, density, empty ground,
   partitions, slope and altitude windows);
2. the survival rule ``[scatter] method`` names (:data:`RULES`): ``random``
   (Poisson-disk ``min_distance`` thinning in candidate order) or
   ``ecosystem`` (growth, competition, self-thinning, then ``min_distance``
   thinning with the strongest plants first);
3. :func:`~forest.scatter.attributes.tree_attributes` — yaw, scale, phase,
   individual, tint, partition and orientation of the survivors (with the
   emergents and snags of :mod:`forest.scatter.canopy`; its stands and
   clearings thin candidates in step 1's density stage);
4. :func:`~forest.scatter.ground_cover.scatter_ground_cover` — the
   ``[[ground_cover]]`` plants near the camera path, appended as rows of
   their own species (:mod:`forest.scatter.models`);
5. the trees placed by hand (``[[tree]]``, :mod:`forest.scatter.placed`): the scattered
   trees around each are left out (the report's stage ``placed tree``) and the placed
   ones appended last, ids after every other row's;
6. the provenance (:mod:`forest.scatter.provenance`): the hashes of the input
   files go into the InstanceSet's metadata.

The species are resolved through the tree library once, for the leaf colours
the tints jitter about (:mod:`forest.tint`).

Same config + seed ⇒ the same InstanceSet, byte for byte.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..config import Config
from ..errors import ConfigError
from ..instances import COLUMNS, InstanceSet
from ..library import Library
from ..maps import MapSet
from ..terrain import Terrain, load_terrain
from ..tint import tint_params
from .attributes import tree_attributes
from .candidates import SHARED_STAGES, SPECIES_STAGES, Progress, candidates, no_progress, random_streams
from .canopy import dead_fractions
from .ecosystem import ecosystem_rule
from .ground_cover import CoverResult, scatter_ground_cover
from .models import model_settings, resolve_models, scatter_models
from .placed import STAGE as PLACED_STAGE
from .placed import check_places, clear_radii, cleared, placed_columns
from .provenance import check_provenance, cover_digest, input_hashes, placed_digest
from .report import ScatterReport, species_keys, tally
from .survival import SurvivalRule, random_rule

RULES: dict[str, SurvivalRule] = {"random": random_rule, "ecosystem": ecosystem_rule}


def scatter(
    config: Config,
    progress: Progress | None = None,
    terrain: Terrain | None = None,
    library: Library | None = None,
    colour: np.ndarray | None = None,
) -> tuple[InstanceSet, ScatterReport]:
    """Scatter the trees a config describes.  Raises :class:`~forest.errors.ForestError` on bad input.

    ``library`` (default :func:`forest.library.open_library`) gives each species'
    leaf colour, about which the tints are jittered; ``colour``, the colour map's tint grid when the caller
    has read it already (:class:`~forest.maps.MapSet`).
    """
    if config.scatter.edge_taper is not None and config.maps.presence is None:
        raise ConfigError(config.path, "scatter.edge_taper", "needs [maps] presence: the taper follows its edge")
    t0 = time.perf_counter()
    step = progress or no_progress
    rule = RULES[config.scatter.method]
    # The inputs are read before the first progress line, so a user's mistake in one (an unreadable map,
    # heightmap or mesh) is the command's one line even in a render farm's log.
    terrain = terrain or load_terrain(config.terrain, config.path)
    if library is None:
        from ..library import open_library

        library = open_library()
    models = resolve_models(config, library)
    placed_heights = check_places(config, terrain)
    maps = MapSet(config, colour)
    step(0.15, "terrain, species and maps read")
    tints = tint_params(model_settings(config), models, config.seed)
    dead = dead_fractions([sp.dead for sp in config.species], models)
    inputs = input_hashes(config)
    rng = random_streams(config.seed)

    cand, fate, species_draw = candidates(config, terrain, maps, rng, step)
    survival = rule(cand, config, terrain, step)
    placed = config.model.tree
    placed_stage = (PLACED_STAGE,) if placed else ()
    stages = SHARED_STAGES + survival.stages + placed_stage
    # The rule's codes 1, 2, … follow the shared stages' in the per-candidate fates.
    fate[cand.index] = np.where(survival.fate > 0, survival.fate + len(SHARED_STAGES), 0)
    alive, size, columns = survival.alive, survival.size, survival.columns
    if placed:
        # Survivors standing where a [[tree]] is placed: rejected by its stage, the last code.
        gone = cleared(cand.position[alive], placed, clear_radii(config, models))
        if gone.any():
            rows = np.flatnonzero(alive)[gone]
            fate[cand.index[rows]] = len(stages)
            alive = alive.copy()
            alive[rows] = False
            size = None if size is None else size[~gone]
            columns = {key: col[~gone] for key, col in columns.items()}

    step(0.9, "attributes")
    meta = {
        "source": config.path.name if config.path else "",
        "height_range": list(terrain.height_range),
        **survival.meta,
        "inputs": inputs,
    }
    digest = cover_digest(config)
    if digest is not None:
        meta["ground_cover"] = digest
    if placed:
        meta["placed"] = placed_digest(config)
    trees = cand if alive.all() else cand.subset(alive)
    inst = tree_attributes(trees, size, config, terrain, maps, rng, meta, tints, dead)
    names = list(inst.species_names)
    rejected, by_species = tally(fate, species_draw, stages, SPECIES_STAGES + survival.stages + placed_stage, names)
    counts = inst.counts()
    kept = len(inst)
    cover: list[CoverResult] = []
    if config.model.ground_cover:
        step(0.95, "ground cover")
        cover = scatter_ground_cover(config, terrain, maps, tints)
        inst = with_rows(inst, cover, scatter_models(config))
    if placed:
        first = config.scatter.count + sum(r.candidates for r in cover)
        inst = with_columns(inst, placed_columns(config, terrain, maps, tints, placed_heights, first))
    report = ScatterReport(
        candidates=config.scatter.count,
        kept=kept,
        area_m2=terrain.area,
        rejected=rejected,
        rejected_by_species=by_species,
        species=counts["species"],
        partitions=counts["partitions"],
        columns=columns,
        individuals={key: s.individual_count for key, s in zip(species_keys(names), config.species)},
        cover={key: (r.kept, r.candidates) for key, r in zip(species_keys([r.name for r in cover]), cover)},
        placed=len(placed),
    )
    if maps.partition is not None and maps.partition.unlabelled_pixels:
        pm = maps.partition
        report.unlabelled_pixels = pm.unlabelled_pixels
        report.unlabelled_colours = pm.unlabelled_colours
        cols = ", ".join("#{:02x}{:02x}{:02x}".format(*c) for c in pm.unlabelled_colours)
        report.warnings.append(
            f"{pm.unlabelled_pixels:,} partition-map pixels match no label colour "
            f"(e.g. {cols}); their trees go to partition 'unlabelled'"
        )
    report.seconds = time.perf_counter() - t0
    step(1.0, "done")
    return inst, report


def with_rows(inst: InstanceSet, cover: list[CoverResult], names: list[str]) -> InstanceSet:
    """The trees followed by the ground cover's rows, with ``species_names`` = ``names`` (trees' then cover's)."""
    return with_columns(inst, {c: np.concatenate([r.columns[c] for r in cover]) for c in COLUMNS}, names)


def with_columns(inst: InstanceSet, columns: dict[str, np.ndarray], names: list[str] | None = None) -> InstanceSet:
    """``inst`` with ``columns`` appended as rows, and ``species_names`` = ``names`` (default: its own)."""
    cols = {c: np.concatenate([getattr(inst, c), columns[c]]) for c in COLUMNS}
    return InstanceSet(
        **cols,
        species_names=list(inst.species_names) if names is None else names,
        partition_names=list(inst.partition_names),
        extent=inst.extent,
        seed=inst.seed,
        meta=inst.meta,
    )


def scene_instances(
    config: Config,
    instances_path: str | Path | None = None,
    progress: Progress | None = None,
    terrain: Terrain | None = None,
    library: Library | None = None,
    colour: np.ndarray | None = None,
) -> InstanceSet:
    """The scene's InstanceSet: loaded from ``instances_path`` if given (and checked against the
    config's species and input files, :func:`~forest.scatter.provenance.check_provenance`), else scattered
    (``colour``: as :func:`scatter`'s)."""
    if instances_path is None:
        return scatter(config, progress=progress, terrain=terrain, library=library, colour=colour)[0]
    inst = InstanceSet.load(instances_path)
    check_provenance(inst, config, instances_path)
    return inst
