"""Survival rules: which candidates that passed the shared rules become trees.

A rule is a function ``rule(candidates, config, terrain, progress) -> Survival``
(:data:`SurvivalRule`).  Two
stand side by side, chosen by ``[scatter] method``:

* ``random`` (:func:`random_rule`, here) — every candidate survives, except
  that with ``[scatter] min_distance`` = r > 0 the survivors are thinned to a
  Poisson-disk set in candidate order (:func:`~forest.scatter.poisson.poisson_thin`:
  sequential dart throwing, Cook 1986).  Sizes are uniform in each species'
  ``scale`` range.
* ``ecosystem`` (:func:`forest.scatter.ecosystem.ecosystem_rule`) — seeds
  establish by site fitness, grow, and die by competition and self-thinning
  (after Deussen et al. 1998); with ``min_distance`` the survivors are thinned
  by the same dart throwing, the strongest plants first.

Each rule names the stages it can reject at; every candidate it drops carries one
of them, so the report's counts add up.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..config import Config
from ..terrain import Terrain
from .candidates import Candidates, Progress
from .poisson import poisson_thin


@dataclass
class Survival:
    """A survival rule's verdict over ``m`` candidates.

    ``fate`` (m,) uint8: 0 survives, ``1 + s`` rejected by ``stages[s]``.
    ``size`` (survivors,) in [0, 1]: the position of each tree in its species'
    ``scale`` range, or None to draw it uniformly.  ``columns`` are per-survivor
    arrays for the report; ``meta`` goes into the InstanceSet's metadata.
    """

    stages: tuple[str, ...]
    fate: np.ndarray
    size: np.ndarray | None = None
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def alive(self) -> np.ndarray:
        """(m,) bool: the candidates that survive (``fate == 0``)."""
        return self.fate == 0


SurvivalRule = Callable[[Candidates, Config, Terrain, Progress], Survival]


def random_rule(cand: Candidates, config: Config, _terrain: Terrain, progress: Progress) -> Survival:
    """Keep every candidate; with ``min_distance`` > 0 keep a Poisson-disk subset in candidate order."""
    fate = np.zeros(len(cand), dtype=np.uint8)
    r = config.scatter.min_distance
    if r > 0 and len(cand):
        progress(0.6, "min_distance")
        fate[~poisson_thin(cand.position, r)] = 1
    return Survival(("min_distance",), fate, meta={"method": "random"})
