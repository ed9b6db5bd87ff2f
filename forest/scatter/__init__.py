"""Scatter: candidate sites on the terrain → the rules every method obeys → a survival rule → an InstanceSet.

Modules, one concept each:

* :mod:`~forest.scatter.candidates` — sites drawn uniformly by surface area and
  the shared rules: presence, density, species draw / empty ground,
  per-species partitions, slope and altitude windows;
* :mod:`~forest.scatter.survival` — the survival-rule contract and the
  ``random`` rule, with :mod:`~forest.scatter.poisson` (exact vectorised
  Poisson-disk thinning for ``min_distance``);
* :mod:`~forest.scatter.ecosystem` — the ``ecosystem`` rule: site fitness,
  growth, competition, self-thinning, shade tolerance (Deussen et al. 1998);
* :mod:`~forest.scatter.attributes` — yaw, scale, phase, individual, tint,
  partition and orientation of the survivors;
* :mod:`~forest.scatter.ground_cover` — ``[[ground_cover]]``: small plants at
  a density per m² near the camera path, rows of their own species;
* :mod:`~forest.scatter.models` — the species of an InstanceSet (``[[species]]``
  then ``[[ground_cover]]``), their settings, fields and individuals;
* :mod:`~forest.scatter.provenance` — the input files' hashes an InstanceSet
  records, checked when a saved set is loaded for a config;
* :mod:`~forest.scatter.report` — :class:`ScatterReport`, the summary;
* :mod:`~forest.scatter.pipeline` — :func:`scatter` and :func:`scene_instances`.
"""

from __future__ import annotations

from .models import model_field, model_settings, resolve_models, scatter_models
from .pipeline import RULES, scatter, scene_instances
from .provenance import check_provenance, input_hashes
from .report import ScatterReport

__all__ = [
    "RULES",
    "ScatterReport",
    "check_provenance",
    "input_hashes",
    "model_field",
    "model_settings",
    "resolve_models",
    "scatter",
    "scatter_models",
    "scene_instances",
]
