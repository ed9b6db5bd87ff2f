"""The scatter summary: how many candidates each rule rejected, per stage and per species."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class ScatterReport:
    """What a scatter did.

    Every candidate ends either as a tree or as a rejection by exactly one stage
    (the first that rejected it), so ``kept + sum(rejected.values()) == candidates``.
    ``rejected_by_species`` splits the stages that come after the species draw.
    ``columns`` holds method-specific per-tree arrays aligned with the InstanceSet's
    tree rows (the ecosystem's canopy ``radius`` and ``shade_tolerant``).  Ground cover
    is counted apart (``cover``: plants kept and sites drawn per ``[[ground_cover]]``);
    its rows follow the trees' in the InstanceSet.
    """

    candidates: int
    kept: int
    area_m2: float
    rejected: dict[str, int] = field(default_factory=dict)  # stage → count
    rejected_by_species: dict[str, dict[str, int]] = field(default_factory=dict)
    species: dict[str, int] = field(default_factory=dict)
    partitions: dict[str, int] = field(default_factory=dict)
    unlabelled_pixels: int = 0
    unlabelled_colours: list[tuple[int, int, int]] = field(default_factory=list)
    seconds: float = 0.0
    warnings: list[str] = field(default_factory=list)
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    individuals: dict[str, int] = field(default_factory=dict)  # tree species → individuals drawn from
    cover: dict[str, tuple[int, int]] = field(default_factory=dict)  # ground cover → (plants, candidates)
    placed: int = 0  # trees placed by hand ([[tree]]), not counted in kept

    def lines(self) -> list[str]:
        """The report as the CLI prints it: totals, species, individuals, partitions, rejections, cover, warnings."""
        out = [
            f"{self.kept:,} trees from {self.candidates:,} candidates over {self.area_m2 / 1e6:.3f} km² "
            f"in {self.seconds:.2f} s"
        ]
        out.append("  species:    " + ", ".join(f"{k} {v:,}" for k, v in self.species.items()))
        if self.individuals:
            out.append("  individuals: " + ", ".join(f"{k} {v}" for k, v in self.individuals.items()))
        out.append("  partitions: " + ", ".join(f"{k} {v:,}" for k, v in self.partitions.items()))
        rej = [f"{k} {v:,}" for k, v in self.rejected.items() if v]
        out.append("  rejected:   " + (", ".join(rej) if rej else "none"))
        for sp, d in self.rejected_by_species.items():
            r = [f"{k} {v:,}" for k, v in d.items() if v]
            if r:
                out.append(f"    {sp}: " + ", ".join(r))
        if self.cover:
            out.append(
                "  ground cover: "
                + ", ".join(f"{k} {kept:,} (of {cand:,} sites)" for k, (kept, cand) in self.cover.items())
            )
        if self.placed:
            out.append(f"  placed by hand: {self.placed:,} ([[tree]]; not in the counts above)")
        out.extend(f"  warning: {w}" for w in self.warnings)
        return out


def species_keys(names: list[str]) -> list[str]:
    """Report keys of the ``[[species]]`` entries: the model, with ``[k]`` where a model repeats."""
    return [nm if names.count(nm) == 1 else f"{nm}[{k}]" for k, nm in enumerate(names)]


def tally(
    fate: np.ndarray, species: np.ndarray, stages: tuple[str, ...], per_species: tuple[str, ...], names: list[str]
) -> tuple[dict[str, int], dict[str, dict[str, int]]]:
    """Count rejections from per-candidate fates.

    ``fate[i]`` is 0 for a tree and ``1 + s`` for a candidate rejected by ``stages[s]``;
    ``species[i]`` the candidate's species draw (``len(names)`` for empty ground).
    Returns ``rejected`` (stage → count, every stage listed) and, for the stages in
    ``per_species``, the counts per species — one joint histogram of (fate, species).
    """
    n_sp = len(names)
    joint = np.bincount(fate.astype(np.int64) * (n_sp + 1) + species, minlength=(len(stages) + 1) * (n_sp + 1))
    joint = joint.reshape(len(stages) + 1, n_sp + 1)
    rejected = {s: int(joint[1 + i].sum()) for i, s in enumerate(stages)}
    by_species = {
        key: {s: int(joint[1 + stages.index(s), k]) for s in per_species} for k, key in enumerate(species_keys(names))
    }
    return rejected, by_species
