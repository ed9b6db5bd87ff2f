"""The shared candidate stages: sites on the terrain and the rules every method obeys.

Both scatter methods start here.  ``count`` candidate sites are drawn uniformly
by *surface area* (:meth:`forest.terrain.Terrain.sample_points`: a triangle with
probability ∝ its area, a point in it by the square-root warp, Osada et al.
2002), so the expected number of candidates per square metre of real surface is
``count / area`` whatever the terrain's parametrisation.  Each candidate then
meets these rules in order; the first that fails rejects it:

==============  ===============================================================
stage           a candidate at map coordinates (u, v) is rejected when
==============  ===============================================================
presence        the presence map's nearest pixel is below the threshold
water           it stands under ``[terrain] water`` or less than its ``shore`` above it
density         its uniform draw ξ_d ≥ the density map's bilinear value times the
                stand factor of ``[scatter] clumping`` (:mod:`forest.scatter.canopy`)
empty ground    its species draw ξ_s·100 falls past Σ percent (unclaimed ground); with
                ``[scatter] grouping`` ξ_s is coupled to a field of species patches
                (:mod:`forest.scatter.canopy`)
partition       its species lists ``partitions`` and the region under it is not one
slope           the terrain slope θ = arccos(n_y) is outside [slope_min, slope_max]
altitude        its height y is outside the species' ``altitude`` window
==============  ===============================================================

Every function here is a vectorised predicate over arrays; :func:`candidates`
runs them and returns the survivors as :class:`Candidates` together with each
candidate's *fate* (the stage that rejected it), from which the report counts.

Random numbers come from one seeded stream per quantity (:data:`STREAMS`), each
drawing one value per candidate, so a candidate's draws depend only on its index:
a map edit that removes one tree leaves every other tree's id and attributes as
they were.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..config import Config, SpeciesConfig
from ..maps import MapSet
from ..terrain import Terrain
from .canopy import clumping_density, clumping_on, grouped_draw, grouping_on

#: One stream per quantity, in this order for good: a new quantity is appended at the end, so the
#: streams before it (and every existing tree's position, yaw, scale, phase) stay as they were.
STREAMS = ("position", "density", "species", "yaw", "scale", "phase", "individual", "emergent", "dead")
TAG = 0x5CA77E2
SHARED_STAGES = ("presence", "water", "density", "empty ground", "partition", "slope", "altitude")
SPECIES_STAGES = ("partition", "slope", "altitude")  # stages reported per species
SLOPE_TOLERANCE = 1e-9  # degrees: slopes on a window's edge (up to round-off) are inside

Progress = Callable[[float, str], None]


def no_progress(fraction: float, message: str = "") -> None:
    """A progress callback that reports nowhere."""


def random_streams(seed: int) -> dict[str, np.random.Generator]:
    """One independent PCG64 generator per quantity in :data:`STREAMS`, spawned from (seed, TAG).

    Child k of ``SeedSequence([seed, TAG]).spawn(n)`` depends on k alone, not on n:
    appending a stream leaves the earlier ones unchanged.
    """
    ss = np.random.SeedSequence([seed, TAG])
    return {name: np.random.Generator(np.random.PCG64(s)) for name, s in zip(STREAMS, ss.spawn(len(STREAMS)))}


@dataclass
class Candidates:
    """Candidate sites that passed the shared rules, in candidate order (ascending ``index``).

    ``index`` (m,) int64 is the candidate number, later the tree's ``id``;
    ``position`` (m, 3) and ``normal`` (m, 3) float64 (Y up, unit normals);
    ``species`` (m,) int64 index into ``[[species]]``; ``u``, ``v`` (m,) map
    coordinates; ``slope`` (m,) degrees.
    """

    index: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    species: np.ndarray
    u: np.ndarray
    v: np.ndarray
    slope: np.ndarray

    def __len__(self) -> int:
        return len(self.index)

    def subset(self, mask: np.ndarray) -> Candidates:
        """The candidates selected by ``mask`` (a boolean mask or an index array), every column alike."""
        return Candidates(
            self.index[mask],
            self.position[mask],
            self.normal[mask],
            self.species[mask],
            self.u[mask],
            self.v[mask],
            self.slope[mask],
        )


# -- the rules, one predicate each ----------------------------------------------------


def density_keeps(maps: MapSet, u: np.ndarray, v: np.ndarray, draw: np.ndarray) -> np.ndarray:
    """Thinning by the density map: keep with probability ρ(u, v), i.e. where ξ_d < ρ."""
    return draw < maps.density_at(u, v)


def draw_species(percent: Sequence[float], draw: np.ndarray) -> np.ndarray:
    """Species index by percentages: the k with C_{k−1} ≤ 100·ξ_s < C_k, C the cumulative percents.

    An index equal to ``len(percent)`` is empty ground (the part of 100 % no species claims).
    """
    return np.searchsorted(np.cumsum(percent), draw * 100.0, side="right")


def partition_table(species: Sequence[SpeciesConfig], regions: Sequence[str]) -> np.ndarray:
    """(species, regions) bool: may species k grow in region p (all regions unless it lists some)."""
    allowed = np.ones((len(species), len(regions)), dtype=bool)
    for k, sp in enumerate(species):
        if sp.partitions is not None:
            allowed[k] = [name in sp.partitions for name in regions]
    return allowed


def slope_degrees(normal: np.ndarray) -> np.ndarray:
    """Terrain slope θ = arccos(n_y) in degrees from unit normals (N, 3)."""
    return np.degrees(np.arccos(np.clip(normal[:, 1], -1.0, 1.0)))


def outside(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, tolerance: float = 0.0) -> np.ndarray:
    """True where x ∉ [lo − tolerance, hi + tolerance] (per-row windows)."""
    return (x < lo - tolerance) | (x > hi + tolerance)


def slope_windows(species: Sequence[SpeciesConfig]) -> tuple[np.ndarray, np.ndarray]:
    """(slope_min, slope_max) per species, degrees."""
    return np.array([sp.slope_min for sp in species]), np.array([sp.slope_max for sp in species])


def altitude_windows(species: Sequence[SpeciesConfig]) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) height window per species, metres (±∞ where a species sets none)."""
    lo = np.array([sp.altitude[0] if sp.altitude else -np.inf for sp in species])
    hi = np.array([sp.altitude[1] if sp.altitude else np.inf for sp in species])
    return lo, hi


# -- the shared pipeline ---------------------------------------------------------------


def candidates(
    config: Config,
    terrain: Terrain,
    maps: MapSet,
    rng: dict[str, np.random.Generator],
    progress: Progress = no_progress,
) -> tuple[Candidates, np.ndarray, np.ndarray]:
    """Draw ``[scatter] count`` sites and apply the shared rules.

    Returns the surviving :class:`Candidates`, the fate of every candidate
    (uint8 (n,): 0 alive, ``1 + s`` rejected by ``SHARED_STAGES[s]``) and every
    candidate's species draw (int64 (n,), ``len(species)`` for empty ground).
    Work is done only on the candidates still alive at each stage.
    """
    species = config.species
    n = config.scatter.count
    code = {s: np.uint8(1 + i) for i, s in enumerate(SHARED_STAGES)}
    fate = np.zeros(n, dtype=np.uint8)

    progress(0.3, "candidates")
    xi = rng["position"].random((3, n))
    position, face, bary = terrain.sample_points(xi[0], xi[1], xi[2])
    mu, mv = terrain.to_uv(position[:, 0], position[:, 2])

    keep = maps.present(mu, mv)
    fate[~keep] = code["presence"]
    if terrain.water is not None:
        wet = keep & ~terrain.dry(position[:, 1])
        fate[wet] = code["water"]
        keep &= ~wet
    d_xi = rng["density"].random(n)
    clump = config.scatter.clumping
    if maps.density is not None or clumping_on(clump):
        live = np.flatnonzero(keep)
        if clumping_on(clump):
            rho = clumping_density(clump, terrain.extent, config.seed, position[live, 0], position[live, 2])
            if maps.density is not None:
                rho = rho * maps.density_at(mu[live], mv[live])
            thinned = live[~(d_xi[live] < rho)]
        else:
            thinned = live[~density_keeps(maps, mu[live], mv[live], d_xi[live])]
        fate[thinned] = code["density"]
        keep[thinned] = False

    progress(0.5, "species")
    xi_s = rng["species"].random(n)
    group = config.scatter.grouping
    if grouping_on(group):  # species in patches (forest.scatter.canopy, "Species in groups")
        xi_s = grouped_draw(group, terrain.extent, config.seed, position[:, 0], position[:, 2], xi_s)
    sp_draw = draw_species([sp.percent for sp in species], xi_s)
    empty = keep & (sp_draw >= len(species))
    fate[empty] = code["empty ground"]
    keep &= ~empty
    sp_idx = np.minimum(sp_draw, len(species) - 1)

    if maps.partition is not None and any(sp.partitions is not None for sp in species):
        live = np.flatnonzero(keep)
        allowed = partition_table(species, maps.partition_names)
        bad = live[~allowed[sp_idx[live], maps.partition_at(mu[live], mv[live])]]
        fate[bad] = code["partition"]
        keep[bad] = False

    live = np.flatnonzero(keep)
    normal = terrain.normals_at(face[live], bary[live])
    slope = slope_degrees(normal)
    k = sp_idx[live]
    s_lo, s_hi = slope_windows(species)
    a_lo, a_hi = altitude_windows(species)
    bad_slope = outside(slope, s_lo[k], s_hi[k], SLOPE_TOLERANCE)
    bad_alt = ~bad_slope & outside(position[live, 1], a_lo[k], a_hi[k])
    fate[live[bad_slope]] = code["slope"]
    fate[live[bad_alt]] = code["altitude"]
    ok = ~(bad_slope | bad_alt)
    live = live[ok]
    cand = Candidates(live, position[live], normal[ok], sp_idx[live], mu[live], mv[live], slope[ok])
    return cand, fate, sp_draw
