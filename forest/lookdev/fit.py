"""The outer loop of a fit: render, linearise, step, judge on a held-out render, keep the best.

Each iteration k:

1. renders the light images U_l at θ_k (one primal render per light) with the
   iteration's own seed, and — at the first iteration and at
   :data:`REFRESH` — the albedo elasticities by forward-mode path replay
   (frozen in between: they only set the step, not where the fit goes, since
   the next iteration re-renders the image itself);
2. solves the surrogate exactly (:func:`.solve.step`) → θ_{k+1};
3. renders θ_{k+1} twice with the **held-out seeds** — the same for every
   iterate (common random numbers, so iterates are compared on equal noise) and
   never used to fit — and evaluates the MAP objective (data + priors) on them
   (the data term as the product of the two renders' residuals, unbiased by
   their noise: :meth:`.solve.Problem.objective`).

Guard rails: the best iterate by that held-out objective is the result, not
the last; an iterate worse than the best shrinks the trust box and the next
step starts from the best; the start itself is the first candidate, so a fit
never returns a look worse than the one it started from (it says so when it
keeps the start).  After the fit, every parameter that ends within 1 % of a
bound, or more than :data:`IMPLAUSIBLE` prior σ from its prior mean, is named
in a warning.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .correction import cell_classes, pixel_cells, upsample_operator
from .look import ground_tint, leaf_tints
from .params import Look
from .renders import FitRenderer
from .solve import TRUST, UNDETERMINED, Linearisation, Problem, WeakDirection, step, undetermined, weak_directions

REFRESH: tuple[int, ...] = ()
#: Largest elasticity of a pixel to an albedo multiplier (its light bounced that often on the albedo).
MAX_ELASTICITY = 4.0
#: A colour-map cell whose data information (in prior units) is below this is unseen and held as painted; the
#: others are fitted, the weakly seen ones mostly through the smoothness prior that ties them to their neighbours.
UNSEEN_CELL = 0.01
#: Light images pooled into the surrogate (the latest renders, see :meth:`Fitter._pooled`).
POOL = 8
#: Largest ln-change of any albedo between a pooled image's look and the current one (see :meth:`Fitter._pooled`).
POOL_RADIUS = 0.5
IMPLAUSIBLE = 3.0
HOLDOUT_SEED = 0x0D0E_5EED
#: Offset of the seed of each iteration's second, independent light images.
SECOND_SEED = 0x5EC0_2D


def _quiet(fraction: float, message: str = "") -> None:
    """A progress callback that says nothing."""


def elasticity(derivative: np.ndarray, inverse_image: np.ndarray) -> np.ndarray:
    """e = (∂I/∂ln m) / I per pixel and channel, from a derivative rendered with the same seed as I (path replay:
    the same paths, so the ratio is each pixel's share of light that met m, times how often), clipped to
    [0, :data:`MAX_ELASTICITY`]: an albedo multiplier scales each path by m^(bounces on it)."""
    return np.clip(derivative * inverse_image, 0.0, MAX_ELASTICITY)


def holdout_spp(spp: int) -> int:
    """Samples of each of the two held-out renders: the fit's, rounded up as the multijitter sampler rounds
    (a·⌈n/a⌉, a = ⌊√n⌋), so it does not warn."""
    import math

    n = int(spp)
    a = max(1, math.isqrt(n))
    return a * -(-n // a)


#: Stop when the held-out objective improved by less than this share twice in a row.
STALL = 2e-3


@dataclass
class FitResult:
    """What :meth:`Fitter.run` returns: start and best looks, their (data, prior) objectives, diagnostics."""

    start: Look
    best: Look
    history: list[dict[str, Any]] = field(default_factory=list)  # per iteration: data, prior, total, accepted
    start_objective: tuple[float, float] = (0.0, 0.0)
    best_objective: tuple[float, float] = (0.0, 0.0)
    shares: dict[str, float] = field(default_factory=dict)  # posterior variance share per parameter
    held: dict[str, str] = field(default_factory=dict)  # parameter → why
    warnings: list[str] = field(default_factory=list)
    best_iteration: int = 0
    seconds: float = 0.0
    cell_information: np.ndarray | None = None  # (n, m) the data's information on each map cell, in prior units
    weak: list[WeakDirection] = field(default_factory=list)  # directions the data determine less than the priors


class Fitter:
    """Renders and steps one fit (see the module docstring)."""

    def __init__(self, renderer: FitRenderer, problem: Problem, *, base_map: np.ndarray | None, seed: int):
        self.r = renderer
        self.p = problem
        self.base_map = base_map
        self.seed = int(seed)
        self._up = None
        self._pool: list[tuple[Look, dict[str, np.ndarray], dict[str, np.ndarray]]] = []
        self._last: Linearisation | None = None
        if problem.cells is not None and base_map is not None:
            self._up = upsample_operator(base_map.shape[:2], problem.cells)

    # -- applying a look to the renderer --------------------------------------------------
    def grid(self, look: Look) -> np.ndarray | None:
        """The colour grid at ``look``: the base map times exp(upsampled ln-correction); None without a map."""
        if self.base_map is None:
            return None
        if look.correction is None or self._up is None:
            return self.base_map
        f = self._up @ look.correction.reshape(-1, 3)
        return self.base_map * np.exp(f).reshape(self.base_map.shape)

    def apply(self, look: Look) -> None:
        """Set the renderer's lights, haze and albedos (leaf and ground tints, colour grid) to ``look``."""
        st = self.p.start
        self.r.set_lights(self.p.light_scales(look))
        self.r.set_haze(look.get("haze", st.haze))
        leaf0 = np.ones((self.p.n_species, 3)) if st.leaf_tint0 is None else st.leaf_tint0
        self.r.set_albedo(
            leaf0 * leaf_tints(look, self.p.n_species), st.ground_tint0 * ground_tint(look), self.grid(look)
        )

    def render(self, look: Look, seed: int, spp: int | None = None) -> np.ndarray:
        """Linear image of ``look`` rendered with ``seed`` (and ``spp``, default the renderer's)."""
        self.apply(look)
        return self.r.render(seed, spp)

    def holdout(self, look: Look) -> tuple[np.ndarray, np.ndarray]:
        """Two independent held-out renders of ``look`` (seeds never used to fit, the same for every look)."""
        spp = holdout_spp(self.r.spp)
        return self.render(look, HOLDOUT_SEED, spp), self.render(look, HOLDOUT_SEED + 1, spp)

    # -- linearisation --------------------------------------------------------------------
    def linearise(self, look: Look, k: int, previous: Linearisation | None) -> Linearisation:
        """The surrogate at ``look`` for iteration ``k``: fresh light images (two seeds), pooled; the albedo
        elasticities are rendered at the first iteration and at :data:`REFRESH`, else taken from ``previous``.
        """
        self.apply(look)
        seed = self.seed * 1_000_003 + 7919 * k
        u = self.r.light_images(seed)
        ub = self.r.light_images(seed + SECOND_SEED)  # independent: the step's data term is unbiased by noise
        if k == 0:
            self._pool = []
        self._pool = (self._pool + [(look.copy(), u, ub)])[-POOL:]
        total = sum(u[n] * s for n, s in self.p.light_scales(look).items() if n in u)
        if previous is not None and k not in REFRESH:
            lin = Linearisation(
                look,
                u,
                previous.leaf_e,
                previous.ground_e,
                previous.grid_e,
                previous.grid_cells,
                light_images_b=ub,
                grid_at=previous.grid_at,
            )
            return self._pooled(lin)
        inv = np.where(total > 1e-7, 1.0 / np.maximum(total, 1e-7), 0.0)
        leaf_e = ground_e = grid_e = cells = None
        groups = {s.group for s in self.p.free}
        if "leaves" in groups:
            leaf_e = np.stack(
                [elasticity(self.r.log_derivative("leaves", seed, species=s), inv) for s in range(self.p.n_species)]
            )
        if "ground" in groups:
            ground_e = elasticity(self.r.log_derivative("ground", seed), inv)
        if look.correction is not None and self.p.cells is not None and self._up is not None:
            lay = self.r.layers
            cells = pixel_cells(lay["u"].ravel(), lay["v"].ravel(), self.p.cells)
            cur = self.grid(look)
            assert cur is not None
            classes = cell_classes(self.p.cells).ravel()
            grid_e = np.zeros((9, *total.shape))
            for c in range(9):
                ind = (classes == c).astype(np.float64)
                tangent = cur * (self._up @ ind).reshape(cur.shape[:2])[..., None]
                if not tangent.any():
                    continue
                grid_e[c] = elasticity(self.r.log_derivative("grid", seed, tangent=tangent), inv)
        grid_at = None if look.correction is None else look.correction.copy()
        return self._pooled(Linearisation(look, u, leaf_e, ground_e, grid_e, cells, light_images_b=ub, grid_at=grid_at))

    def _pooled(self, lin: Linearisation) -> Linearisation:
        """``lin`` with each light image the mean of this fit's light images so far, each carried to ``lin``'s
        albedos by the elasticities (U_j ⊙ exp(Σ e (ln m_k − ln m_j))): their noise averages down with every
        iteration.  The carry is first order in ln m — exact for singly scattered light, not for the rest — so
        only images rendered within :data:`POOL_RADIUS` of ``lin``'s albedos (largest ln-change of any albedo or
        map cell) are pooled: a fit's first, long steps do not drag their start's images along.  Images rendered
        at another haze density are not pooled (their difference is not a product)."""
        haze = lin.look.get("haze", self.p.start.haze)
        same = [
            entry
            for entry in self._pool
            if abs(entry[0].get("haze", self.p.start.haze) - haze) < 1e-12
            and self._albedo_distance(entry[0], lin.look) <= POOL_RADIUS
        ]
        if len(same) <= 1:
            return lin
        out: dict[str, np.ndarray] = {}
        out_b: dict[str, np.ndarray] = {}
        for lk, u, ub in same:
            f = np.exp(self.p.albedo_exponent(lin.look, lk, lin, next(iter(u.values())).shape))
            for name, img in u.items():
                out[name] = out.get(name, 0.0) + img * f / len(same)
            for name, img in ub.items():
                out_b[name] = out_b.get(name, 0.0) + img * f / len(same)
        return replace(lin, light_images=out, light_images_b=out_b)

    def _albedo_distance(self, a: Look, b: Look) -> float:
        """Largest ln-change of any albedo multiplier or map cell between two looks."""
        d = [
            np.abs(np.log(leaf_tints(a, self.p.n_species)) - np.log(leaf_tints(b, self.p.n_species))).max(),
            np.abs(np.log(ground_tint(a)) - np.log(ground_tint(b))).max(),
        ]
        if a.correction is not None and b.correction is not None:
            d.append(np.abs(a.correction - b.correction).max())
        return float(max(d))

    # -- the loop -------------------------------------------------------------------------
    def run(self, start: Look, *, iterations: int, progress: Callable[[float, str], None] | None = None) -> FitResult:
        """Fit from ``start`` for at most ``iterations`` (fewer after two stalls); the best held-out iterate wins."""
        t0 = time.perf_counter()
        say = progress if progress is not None else _quiet
        res = FitResult(start=start.copy(), best=start.copy())
        img0 = self.holdout(start)
        current = start.copy()
        lin: Linearisation | None = None
        trust = TRUST
        stalls = 0
        best_total = start_data = 0.0
        for k in range(iterations):
            lin = self.linearise(current, k, lin)
            self._last = lin
            if k == 0:
                # Which parameters the reference determines; the start is judged on the same terms as the iterates.
                self._decide_held(current, lin, res)
                lin = replace(lin, look=current)
                res.start = current.copy()
                res.best = current.copy()
                res.start_objective = res.best_objective = self.p.objective(current, *img0)
                start_data, best_total = res.start_objective[0], sum(res.start_objective)
                res.history.append(
                    {
                        "iteration": 0,
                        "data": start_data,
                        "prior": res.start_objective[1],
                        "total": best_total,
                        "accepted": True,
                    }
                )
                say(0.0, f"start: objective {best_total:.4g}")
            candidate = step(self.p, lin, trust=trust)
            data, prior = self.p.objective(candidate, *self.holdout(candidate))
            total = data + prior
            accepted = total < best_total and data <= start_data
            res.history.append({"iteration": k + 1, "data": data, "prior": prior, "total": total, "accepted": accepted})
            if accepted:
                gain = (best_total - total) / max(abs(best_total), 1e-30)
                stalls = stalls + 1 if gain < STALL else 0
                best_total = total
                res.best, res.best_objective, res.best_iteration = candidate.copy(), (data, prior), k + 1
                current = candidate
                trust = min(TRUST, trust * 1.5)
            else:
                stalls += 1
                trust *= 0.5
                current = res.best.copy()
            say((k + 1) / iterations, f"iteration {k + 1}: objective {total:.4g} (best {best_total:.4g})")
            if stalls >= 2:
                break
        res.warnings += self._flags(res)
        res.seconds = time.perf_counter() - t0
        return res

    def _decide_held(self, look: Look, lin: Linearisation, res: FitResult) -> None:
        shares, info, (fisher, names) = undetermined(self.p, look, lin)
        res.shares = shares
        res.held.update(self.p.held_reasons)
        for name, share in shares.items():
            if share > UNDETERMINED:
                self.p.held.add(name)
                res.held[name] = f"undetermined: the reference narrows its prior by {100 * (1 - share):.0f} %"
        for name in list(self.p.held):
            if name in look.values:
                look.held[name] = look.values.pop(name)
        keep = [i for i, n in enumerate(names) if n not in self.p.held]
        res.weak = weak_directions(fisher[np.ix_(keep, keep)], [names[i] for i in keep])
        if info is not None and self.p.cells is not None:
            res.cell_information = info.reshape(self.p.cells)
            held = info < UNSEEN_CELL
            self.p.held_cells = held
            if held.any():
                res.held["colour map"] = f"{int(held.sum())} of {held.size} cells unseen: kept as painted"

    def _flags(self, res: FitResult) -> list[str]:
        out = []
        for s in self.p.free:
            v = res.best.values.get(s.name)
            if v is None:
                continue
            span = s.hi - s.lo
            if abs(v - res.start.get(s.name, v)) < 1e-9:
                continue
            if min(v - s.lo, s.hi - v) <= 0.01 * span:
                high = v - s.lo > s.hi - v
                why = self.driver(res.best, s.name, towards_hi=high)
                if not high and s.natural_lo:
                    out.append(f"{s.label} ({s.name}) ended at {s.natural_lo}" + (f", {why}" if why else ""))
                else:
                    out.append(
                        f"{s.label} ({s.name}) ended on a bound of its range {s.show_range()}: {s.show(v)}"
                        + (f"; {why}" if why else "")
                    )
            z = abs(v - s.mean) / s.sigma
            if z > IMPLAUSIBLE:
                out.append(
                    f"{s.label} ({s.name}) moved implausibly far: {s.show(v)} is {z:.1f} σ from its prior "
                    f"{s.show(s.mean)}"
                )
        if res.best_iteration == 0:
            out.append("no iterate beat the start on the held-out render: the start's look is kept")
        return out

    def driver(self, look: Look, name: str, *, towards_hi: bool) -> str:
        """Which observation pushes parameter ``name`` towards its bound at ``look``: the group of residuals
        (a region and its colour component in statistics mode, the region a block shows in aligned mode) whose
        share of the data's gradient −Σ J r along the bound's direction is largest, as a phrase."""
        lin = self._last
        loss = self.p.loss
        if lin is None or loss is None or not hasattr(loss, "group_of"):
            return ""
        from .solve import _global_jacobian

        r = self.p.data_residuals(self.p.predict(look, lin))
        only = [s for s in self.p.free if s.name == name]
        if not only:
            return ""
        keep = self.p.held
        self.p.held = keep | {s.name for s in self.p.free if s.name != name}
        try:
            j = _global_jacobian(self.p, look, lin, r)[:, 0]
        finally:
            self.p.held = keep
        push = -(j * r) * (1.0 if towards_hi else -1.0)  # > 0: this residual wants the parameter past the bound
        groups = np.bincount(loss.group_of, weights=push, minlength=len(loss.group_names))
        total = float(groups[groups > 0].sum())
        if total <= 0:
            return "the priors, not the data, hold it there"
        k = int(np.argmax(groups))
        return f"driven there by the {loss.group_names[k]} ({100 * groups[k] / total:.0f} % of the data's push)"


def determination(share: float) -> float:
    """How much a reference narrowed a parameter's prior variance, 0–1."""
    return float(np.clip(1.0 - share, 0.0, 1.0))


__all__ = ["UNDETERMINED", "FitResult", "Fitter", "determination"]
