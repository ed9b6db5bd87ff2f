"""One Gauss–Newton step of the fit: a surrogate of the render around the current look, solved exactly.

Around the look θ_k the render is modelled as

    R(θ) = [Σ_l s_l(θ) ⊙ U_l] ⊙ exp( Σ_a e_a ⊙ (ln m_a(θ) − ln m_a(θ_k)) ) ⊙ F(c) / F(c_k)

* U_l — the image of light l at unit scale, rendered at θ_k: the path tracer
  is linear in each light's RGB scale s_l, so the light part is exact;
* e_a = (∂I/∂ln m_a) / I — the elasticity of each pixel and channel to an
  albedo multiplier m_a (a species' leaves, the ground), measured by forward-mode
  path replay; first order in ln m, which is exact for a uniform multiplier
  (light that met it n times scales by mⁿ, and e counts the n);
* F(c) — the colour map's cells c_j (aligned mode) as the bilinear mix the
  renderer makes of them: a pixel's light met the map at points each a bilinear
  blend of its (at most four) cells, so with e_k its elasticity to the class-k
  cell (measured at the cells c⁰, one value per pixel and class, :mod:`.correction`),
  f = Σ_k e_k and a_k = e_k / f the mixing weights there,
  F(c) = (Σ_k a_k e^(c_k − c⁰_k))^f — exact for light that met the map once (an
  arithmetic mean of the cells' colours, not the geometric mean e^(Σ e_k Δc_k) of
  a first-order ln model, which for a sharp map drew the cells into a checkerboard
  of ±20 % errors), raised to f for light that met it more often, and equal to the
  first-order model for small changes.  Its Jacobian is sparse and per channel —
  channel c of the image depends on channel c of the cells only, and each pixel on
  at most four cells — so the system stays (pixels·3) × (cells·3) with ≤ 9
  non-zeros a row instead of a dense matrix (at ``--grid 64``: 12 288 columns).

Through the image model (:mod:`.image_model`: exposure, white balance,
clipping, and a change of haze) and the data residuals (:mod:`.losses`), plus the
priors — (θ − μ)/σ for every global parameter, the map cells' prior (below), and
the constraint that species' relative leaf multipliers sum to zero — :func:`step`
minimises the surrogate's objective inside the parameters' ranges intersected with
a trust box around θ_k for the linearised albedo parameters (its docstring: two
independent renders make the data term unbiased).  The Jacobian of the global
parameters is taken by finite differences of the surrogate (a few dozen cheap
evaluations), the map cells' analytically and sparse.

**The colour map's prior.**  ``map_prior = "edges"`` (the default) lets a painted
map's patches be recovered: each cell's ln-correction c has a weak prior N(0,
:data:`EDGE_CELL_SIGMA`²) around the painted map, and the ln-difference d of every two
4-neighbour cells the Huber penalty λ·s·h(d/s), h(x) = x²/2 for |x| ≤ 1 and |x| − ½
beyond (Huber 1964), s = :data:`EDGE_SCALE`, λ = :data:`EDGE_WEIGHT` — quadratic for
differences within the noise, growing only linearly (total variation, Rudin, Osher &
Fatemi 1992) across an edge, so an edge costs in proportion to its height and not its
square: a patch boundary the data show is kept sharp, while a cell the data see
poorly takes its neighbours' value.  As a residual, r = √(2λ s h(d/s)) with d's sign;
the Gauss–Newton weight of an edge then falls as 1/|d| (iteratively reweighted least
squares).  ``"smooth"`` is the earlier field: N(0, :data:`CELL_SIGMA`²) per cell and
Gaussian neighbour differences of σ = 1/(n − 1) (:func:`cell_smooth`), which forbids
edges and suits a small correction of a map the artist trusts.

When the leaf colours are fitted too (or held as the anchor) the map's mean is the
same thing as the leaf tint: the mean of the free cells' correction is then held at 0
(σ :data:`MEAN_SIGMA`) and the leaf tint carries it.

**What the reference determines.**  At the first step the data's Fisher
information F = J̃ᵀJ̃ of the global parameters (J̃ in prior units, columns
scaled by σ) gives the posterior covariance C = (F + I)⁻¹: C_ii is the share of
a parameter's prior variance left after the data.  A parameter whose share
stays above :data:`UNDETERMINED` (the reference narrows it by less than 10 %) is
held at its start value and reported as undetermined, rather than traded
against the parameters it is confounded with; the others are fitted with
their priors.  A statement about each parameter alone misses the directions the
data leave free *together* (a brighter light and darker albedos): the
eigenvectors of F with the smallest eigenvalues are those directions, and
:func:`weak_directions` names every one the data determine less than the priors
do (eigenvalue below :data:`WEAK`), in the parameters' own terms.  A direction can
also be weak *relative to its parts* while the data determine each part well (a
canopy's multiple scattering tells a darker leaf from a dimmer light, faintly):
with D = diag(F + I), the eigenvectors of D^-½ (F + I) D^-½ whose eigenvalue λ is
below :data:`TRADE_OFF` are the trade-offs — along them the parameters are
determined 1/√λ times less well together than each is alone (the variance
inflation of regression diagnostics; Belsley, Kuh & Welsch, *Regression
Diagnostics*, 1980, ch. 3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp

from .image_model import ImageModel
from .look import camera_gain, ground_tint, haze_colour, leaf_tints, lights
from .losses import PixelLoss, RegionLoss
from .params import Look, Spec, Start

UNDETERMINED = 0.9
#: A direction of the global parameters along which the data's information is below this (in prior units) is weak.
WEAK = 1.0
#: A direction along which the parameters are determined 1/√λ times less well together than alone is a trade-off.
TRADE_OFF = 0.05
#: Prior σ of a colour-map ln-correction cell (``map_prior = "smooth"``).
CELL_SIGMA = 0.5
#: Prior σ of a cell's ln-correction under the edge-preserving prior: weak, so the data decide wherever they see it.
EDGE_CELL_SIGMA = 2.0
#: Huber scale s of the neighbour ln-differences (quadratic below it, linear above).
EDGE_SCALE = 0.05
#: Weight λ of the neighbour penalty: an edge of height d costs about λ·|d|.
EDGE_WEIGHT = 0.05
#: σ of the mean of the free cells' correction when the leaf tint carries the mean.
MEAN_SIGMA = 0.01
#: Prior σ of the ln-correction's change across the whole map: a difference between neighbouring cells of an
#: n-cell side has σ = CELL_SPAN / (n − 1) (a smooth field whose slope is the same at any grid), at least
#: :data:`CELL_SMOOTH_MIN`.
CELL_SPAN = 1.0
CELL_SMOOTH_MIN = 0.02


def cell_smooth(cells: tuple[int, int]) -> float:
    """σ of a difference between neighbouring correction cells (see :data:`CELL_SPAN`)."""
    return max(CELL_SPAN / max(max(cells) - 1, 1), CELL_SMOOTH_MIN)


def huber_residuals(
    d: np.ndarray, scale: float | None = None, weight: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(r, dr/dd) with ½r² = λ·s·h(d/s) (the edge-preserving prior of the module docstring)."""
    scale = EDGE_SCALE if scale is None else scale
    weight = EDGE_WEIGHT if weight is None else weight
    d = np.asarray(d, np.float64)
    a = np.abs(d)
    inner = a <= scale
    k = math.sqrt(weight / scale)
    excess = np.maximum(a - 0.5 * scale, 0.5 * scale)
    r = np.where(inner, k * d, np.sign(d) * np.sqrt(2.0 * weight * excess))
    dr = np.where(inner, k, np.sqrt(weight / (2.0 * excess)))
    return r, dr


#: σ of the sum of species' relative leaf ln-multipliers (a soft equality constraint).
SUM_SIGMA = 0.01
#: Largest change of a linearised ln-albedo in one step (the trust box), at the start; the haze's is its prior σ
#: times trust / TRUST.
TRUST = 0.5


@dataclass
class Linearisation:
    """What the renders at θ_k give the surrogate."""

    look: Look  # θ_k
    light_images: dict[str, np.ndarray]  # parameter name → U_l (H, W, 3)
    leaf_e: np.ndarray | None  # (S, H, W, 3) elasticities to each species' leaf multiplier
    ground_e: np.ndarray | None  # (H, W, 3)
    grid_e: np.ndarray | None  # (9, H, W, 3) elasticities to the class-k cell of each pixel
    grid_cells: np.ndarray | None  # (H·W, 9) cell index of each class per pixel (−1 none)
    light_images_b: dict[str, np.ndarray] | None = None  # a second, independent render of the U_l (unbiased steps)
    grid_at: np.ndarray | None = None  # the map correction at which grid_e was measured

    def class_deltas(self, correction: np.ndarray) -> np.ndarray:
        """(9, H·W, 3): each pixel's class-k cell's ln-change from :attr:`grid_at` to ``correction`` (0 where no
        class-k cell touches the pixel)."""
        assert self.grid_cells is not None and self.grid_at is not None
        dc = (np.asarray(correction) - self.grid_at).reshape(-1, 3)
        padded = np.vstack([dc, np.zeros((1, 3))])  # index −1: no cell, no change
        return padded[self.grid_cells.T]

    def map_factor(self, correction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ln F, S) of the map's bilinear mixing at ``correction`` (:mod:`.solve`'s docstring), (H, W, 3) each."""
        assert self.grid_e is not None
        key = np.asarray(correction).tobytes()
        cache = self.__dict__.setdefault("_map_cache", {})
        if key in cache:
            return cache[key]
        if len(cache) > 8:
            cache.clear()
        d = self.class_deltas(correction).reshape(self.grid_e.shape)
        s = np.einsum("khwc,khwc->hwc", self.grid_e, np.exp(d))
        f = self.grid_e.sum(axis=0)
        ok = f > 1e-12
        lnf = np.where(ok, f * np.log(np.where(ok, s, 1.0) / np.where(ok, f, 1.0)), 0.0)
        cache[key] = (lnf, s)
        return lnf, s

    def other(self) -> Linearisation:
        """The same surrogate over the second, independent light images (itself when there are none)."""
        if self.light_images_b is None:
            return self
        return replace(self, light_images=self.light_images_b, light_images_b=self.light_images)


@dataclass
class Problem:
    """A fit's fixed parts: parameters, priors, the image model and the data term."""

    specs: list[Spec]
    start: Start
    image: ImageModel
    loss: PixelLoss | RegionLoss | None  # set before a fit
    n_species: int
    cells: tuple[int, int] | None = None  # correction grid (aligned colour-map fit)
    held: set[str] = field(default_factory=set)
    held_reasons: dict[str, str] = field(default_factory=dict)  # parameter → why it is held (set before a fit)
    held_cells: np.ndarray | None = None  # (n·m,) bool
    map_prior: str = "edges"  # "edges" | "smooth" (module docstring)
    map_mean_fixed: bool = False  # the leaf tint carries the map's mean
    anchor: str = "none"  # what holds the scale of albedos against light (forest.lookdev.params)

    @property
    def free(self) -> list[Spec]:
        """The specs the fit varies (not held)."""
        return [s for s in self.specs if s.name not in self.held]

    @property
    def cell_sigma(self) -> float:
        """Prior σ of one cell's ln-correction."""
        return EDGE_CELL_SIGMA if self.map_prior == "edges" else CELL_SIGMA

    def cell_free_mask(self) -> np.ndarray:
        """(n·m,) bool: the cells the fit varies."""
        assert self.cells is not None
        n = self.cells[0] * self.cells[1]
        return np.ones(n, bool) if self.held_cells is None else ~self.held_cells

    # -- the surrogate --------------------------------------------------------------------
    def light_scales(self, look: Look) -> dict[str, np.ndarray]:
        """RGB light scales by scene parameter name at ``look`` (with a haze, its colour too)."""
        lt = lights(look, self.start)
        out: dict[str, np.ndarray] = {}
        if lt.sun is not None:
            out["sun_irradiance"] = lt.sun
        if lt.zenith is not None and lt.horizon is not None:
            out["sky_zenith"] = lt.zenith
            out["sky_horizon"] = lt.horizon
        if lt.sky_scale is not None:
            out["sky_scale"] = lt.sky_scale
        if lt.sun_scale is not None:
            out["sun_scale"] = lt.sun_scale  # a sunsky's sun follows its sky's scale
        if self.start.has_haze:
            out["haze_colour"] = haze_colour(self.start, lt)
        return out

    def render_model(self, look: Look, lin: Linearisation) -> np.ndarray:
        """R(θ) of the module docstring (linear, before haze and camera)."""
        scales = self.light_scales(look)
        base = None
        for k, u in lin.light_images.items():
            s = np.asarray(scales.get(k, np.zeros(3)), np.float64)
            base = u * s if base is None else base + u * s
        assert base is not None
        return base * np.exp(self.albedo_exponent(look, lin.look, lin, base.shape))

    def albedo_exponent(self, look: Look, at: Look, lin: Linearisation, shape: tuple[int, ...]) -> np.ndarray:
        """Σ_a e_a ⊙ (ln m_a(look) − ln m_a(at)) (+ the map cells'): the first-order ln-change of the image from
        the albedos of ``at`` to those of ``look``, with ``lin``'s elasticities; (H, W, 3), clipped to ±20."""
        expo = np.zeros(shape)
        if lin.leaf_e is not None:
            d = np.log(leaf_tints(look, self.n_species)) - np.log(leaf_tints(at, self.n_species))
            expo += np.einsum("shwc,sc->hwc", lin.leaf_e, d)
        if lin.ground_e is not None:
            expo += lin.ground_e * (np.log(ground_tint(look)) - np.log(ground_tint(at)))
        if lin.grid_e is not None and look.correction is not None and at.correction is not None:
            expo += lin.map_factor(look.correction)[0] - lin.map_factor(at.correction)[0]
        return np.clip(expo, -20.0, 20.0)

    def photo_model(self, look: Look, render: np.ndarray, rendered_at: Look | None = None) -> np.ndarray:
        """The photo predicted from a render at ``look`` — or, in the surrogate, from a render at
        ``rendered_at`` moved to ``look``'s haze (:mod:`.image_model`)."""
        d_sigma = 0.0
        if rendered_at is not None:
            d_sigma = look.get("haze", self.start.haze) - rendered_at.get("haze", self.start.haze)
        lt = lights(look, self.start)
        return self.image.apply(render, gain=camera_gain(look), d_sigma=d_sigma, airlight=haze_colour(self.start, lt))

    def predict(self, look: Look, lin: Linearisation) -> np.ndarray:
        """The surrogate's photo at ``look``."""
        return self.photo_model(look, self.render_model(look, lin), lin.look)

    # -- residuals --------------------------------------------------------------------------
    def prior_residuals(self, look: Look) -> np.ndarray:
        """Prior residuals at ``look``: (x − μ)/σ of the free globals, the per-channel sum of the species' relative
        leaf ln-multipliers, and with a map its cells, their differences (smooth, or Huber for edges) and mean.
        """
        parts = [np.array([(look.values[s.name] - s.mean) / s.sigma for s in self.free])]
        rel = [s.name for s in self.free if s.name.startswith("leaf") and not s.name.startswith("leaves")]
        if rel:
            for ch in "rgb":
                parts.append(np.array([sum(look.get(f"leaf{s}_{ch}") for s in range(self.n_species)) / SUM_SIGMA]))
        if look.correction is not None and self.cells is not None:
            c = look.correction.reshape(-1, 3)
            parts.append((c / self.cell_sigma).ravel())
            d = (smoothness(self.cells) @ c).ravel()
            parts.append(d / cell_smooth(self.cells) if self.map_prior == "smooth" else huber_residuals(d)[0])
            if self.map_mean_fixed:
                free = self.cell_free_mask()
                parts.append(c[free].mean(axis=0) / MEAN_SIGMA if free.any() else np.zeros(3))
        return np.concatenate(parts) if parts else np.zeros(0)

    def data_residuals(self, photo: np.ndarray) -> np.ndarray:
        """The loss's residuals of a predicted photo (linear)."""
        assert self.loss is not None
        return self.loss.residuals(photo)

    def objective(self, look: Look, image: np.ndarray, image2: np.ndarray | None = None) -> tuple[float, float]:
        """(data, prior) halves of ½‖r‖² for a rendered (or modelled) linear image at ``look``.

        With a second, independent render ``image2`` of the same look the data half is ½ r₁·r₂: its
        expectation is the squared bias ½‖E r‖² alone, without the render's variance that would favour
        less noisy looks (:mod:`.losses`)."""
        d = self.data_residuals(self.photo_model(look, image))
        d2 = d if image2 is None else self.data_residuals(self.photo_model(look, image2))
        p = self.prior_residuals(look)
        return 0.5 * float(d @ d2), 0.5 * float(p @ p)

    # -- packing --------------------------------------------------------------------------
    def pack(self, look: Look) -> np.ndarray:
        """The free coordinates of ``look`` as a vector: free globals in :attr:`free` order, then the free map cells."""
        x = [look.values[s.name] for s in self.free]
        if look.correction is not None:
            x += list(look.correction.ravel()[self._cell_free()])
        return np.asarray(x, np.float64)

    def unpack(self, x: np.ndarray, like: Look) -> Look:
        """Inverse of :meth:`pack`: a copy of ``like`` with the free coordinates set from ``x``."""
        out = like.copy()
        free = self.free
        for s, v in zip(free, x[: len(free)]):
            out.values[s.name] = float(v)
        if out.correction is not None:
            flat = out.correction.ravel().copy()
            flat[self._cell_free()] = x[len(free) :]
            out.correction = flat.reshape(out.correction.shape)
        return out

    def _cell_free(self) -> np.ndarray:
        assert self.cells is not None
        n = self.cells[0] * self.cells[1]
        held = np.zeros(n, bool) if self.held_cells is None else self.held_cells
        return np.repeat(~held, 3)


_SMOOTH: dict[tuple[int, int], sp.csr_matrix] = {}


def smoothness(cells: tuple[int, int]) -> sp.csr_matrix:
    """The 4-neighbour first-difference operator of a ``cells`` grid (cached per shape)."""
    if cells not in _SMOOTH:
        from .correction import smoothness_operator

        _SMOOTH[cells] = smoothness_operator(cells)
    return _SMOOTH[cells]


def _global_jacobian(problem: Problem, look: Look, lin: Linearisation, r0: np.ndarray) -> np.ndarray:
    """Finite differences of the data residuals of the surrogate in each free global parameter."""
    free = problem.free
    cols = []
    for s in free:
        h = 1e-4 * (s.hi - s.lo)
        trial = look.copy()
        v = look.values[s.name]
        step = h if v + h <= s.hi else -h
        trial.values[s.name] = v + step
        r = problem.data_residuals(problem.predict(trial, lin))
        cols.append((r - r0) / step)
    return np.stack(cols, axis=1) if cols else np.zeros((len(r0), 0))


def _grid_jacobian(problem: Problem, look: Look, lin: Linearisation) -> sp.csr_matrix:
    """∂r/∂c of the block residuals (aligned): sparse, from one non-zero per pixel, channel and class."""
    assert isinstance(problem.loss, PixelLoss) and lin.grid_e is not None and lin.grid_cells is not None
    render = problem.render_model(look, lin)
    d_sigma = look.get("haze", problem.start.haze) - lin.look.get("haze", problem.start.haze)
    t = problem.image.transmittance(d_sigma)
    dq = render * t * camera_gain(look)  # ∂Q/∂(ln R) before clipping
    if problem.image.clip:
        dq = np.where(problem.photo_model(look, render, lin.look) >= 1.0, 0.0, dq)
    h, w = render.shape[:2]
    rows, cols, vals = [], [], []
    pix = np.arange(h * w)
    assert look.correction is not None
    # ∂ ln F/∂c_k = f·e_k·exp(Δ_k)/S: the elasticity of the bilinear mixing at this look.
    _, s_mix = lin.map_factor(look.correction)
    f = lin.grid_e.sum(axis=0)
    scale = np.where(s_mix > 1e-12, f / np.maximum(s_mix, 1e-12), 0.0)
    deltas = lin.class_deltas(look.correction).reshape(lin.grid_e.shape)
    for k in range(9):
        idx = lin.grid_cells[:, k]
        ok = idx >= 0
        e = (lin.grid_e[k] * np.exp(deltas[k]) * scale * dq).reshape(-1, 3)
        for c in range(3):
            r = pix[ok] * 3 + c
            rows.append(r)
            cols.append(idx[ok] * 3 + c)
            vals.append(e[ok, c])
    n_cells = problem.cells[0] * problem.cells[1]  # type: ignore[index]
    m = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(h * w * 3, n_cells * 3)
    )
    return problem.loss.project(m[:, problem._cell_free()], problem.photo_model(look, render, lin.look)).tocsr()


def prior_jacobian(problem: Problem, look: Look) -> sp.csr_matrix:
    """∂/∂x of :meth:`Problem.prior_residuals` at ``look`` (sparse; columns as :meth:`Problem.pack`)."""
    free = problem.free
    blocks_rows = []
    ng = len(free)
    nc = int(problem._cell_free().sum()) if look.correction is not None else 0
    g = sp.diags([1.0 / s.sigma for s in free], shape=(ng, ng))
    blocks_rows.append(sp.hstack([g, sp.csr_matrix((ng, nc))]))
    rel = [i for i, s in enumerate(free) if s.name.startswith("leaf") and not s.name.startswith("leaves")]
    if rel:
        for ch in "rgb":
            row = np.zeros(ng)
            for i in rel:
                if free[i].name.endswith("_" + ch):
                    row[i] = 1.0 / SUM_SIGMA
            blocks_rows.append(sp.hstack([sp.csr_matrix(row[None]), sp.csr_matrix((1, nc))]))
    if look.correction is not None and problem.cells is not None:
        n = problem.cells[0] * problem.cells[1]
        keep = problem._cell_free()
        eye = sp.identity(n * 3, format="csr") / problem.cell_sigma
        d3 = sp.kron(smoothness(problem.cells), sp.identity(3), format="csr")
        if problem.map_prior == "smooth":
            d3 = d3 / cell_smooth(problem.cells)
        else:
            d = d3 @ look.correction.reshape(-1)
            d3 = sp.diags(huber_residuals(d)[1]) @ d3
        blocks_rows.append(sp.hstack([sp.csr_matrix((n * 3, ng)), eye[:, keep]]))
        blocks_rows.append(sp.hstack([sp.csr_matrix((d3.shape[0], ng)), d3.tocsr()[:, keep]]))
        if problem.map_mean_fixed:
            cf = problem.cell_free_mask()
            row = sp.kron(sp.csr_matrix(cf[None].astype(np.float64) / max(int(cf.sum()), 1)), sp.identity(3))
            blocks_rows.append(sp.hstack([sp.csr_matrix((3, ng)), (row.tocsr() / MEAN_SIGMA)[:, keep]]))
    return sp.vstack(blocks_rows, format="csr")


@dataclass
class WeakDirection:
    """A direction of the global parameters the data leave weak: less determined than the priors (``kind =
    "prior"``, ``information`` the eigenvalue of F in prior units), or a trade-off whose parts are each well
    determined (``kind = "trade-off"``, ``information`` the eigenvalue λ of the normalised information)."""

    information: float
    components: dict[str, float]  # parameter → its weight in the unit eigenvector (largest first)
    kind: str = "prior"

    def describe(self, labels: dict[str, str] | None = None, top: int = 4) -> str:
        """``+0.71 light level − 0.62 ground colour g …``: the largest components, and why the direction is weak."""
        labels = labels or {}
        items = sorted(self.components.items(), key=lambda kv: -abs(kv[1]))[:top]
        terms = " ".join(f"{'−' if w < 0 else '+'}{abs(w):.2f} {labels.get(n, n)}" for n, w in items)
        if self.kind == "trade-off":
            why = f"a trade-off: determined {1 / math.sqrt(max(self.information, 1e-12)):.0f}× less well together"
            return f"{terms.lstrip('+')} ({why} than each alone)"
        return f"{terms.lstrip('+')} (information {self.information:.3g} × the prior's)"


def _direction(v: np.ndarray, names: list[str]) -> dict[str, float]:
    """A unit vector's components ≥ 0.1, signed so the largest is positive, largest first."""
    v = v * np.sign(v[np.argmax(np.abs(v))])
    comp = {n: float(w) for n, w in zip(names, v) if abs(w) >= 0.1}
    return dict(sorted(comp.items(), key=lambda kv: -abs(kv[1])))


def weak_directions(
    f: np.ndarray, names: list[str], threshold: float = WEAK, trade_off: float = TRADE_OFF
) -> list[WeakDirection]:
    """The weak directions of the data's Fisher information ``f`` (prior units): its eigenvectors with
    eigenvalues below ``threshold``, weakest first, then the trade-offs — eigenvectors of the normalised posterior
    information D^-½ (f + I) D^-½ with eigenvalues below ``trade_off`` — that are not one of those already."""
    if not len(names):
        return []
    f = 0.5 * (f + f.T)
    vals, vecs = np.linalg.eigh(f)
    out, seen = [], []
    for k in np.argsort(vals):
        if vals[k] >= threshold:
            break
        seen.append(vecs[:, k])
        out.append(WeakDirection(float(max(vals[k], 0.0)), _direction(vecs[:, k], names)))
    post = f + np.eye(len(names))
    d = np.sqrt(np.diag(post))
    lam, vecs = np.linalg.eigh(post / np.outer(d, d))
    for k in np.argsort(lam):
        if lam[k] >= trade_off:
            break
        v = vecs[:, k] / d  # back to prior units, to compare with the prior-weak ones
        v /= np.linalg.norm(v)
        if any(abs(v @ u) > 0.8 for u in seen):
            continue
        out.append(WeakDirection(float(lam[k]), _direction(vecs[:, k], names), "trade-off"))
    return out


def undetermined(
    problem: Problem, look: Look, lin: Linearisation
) -> tuple[dict[str, float], np.ndarray | None, tuple[np.ndarray, list[str]]]:
    """(posterior/prior variance share of each free global parameter, data information per map cell, and the
    data's Fisher information in prior units over the free global parameters — with the colour map's mean per
    channel, ``map_mean_r/g/b``, when it is free — with their names, for :func:`weak_directions`)."""
    r0 = problem.data_residuals(problem.predict(look, lin))
    jg = _global_jacobian(problem, look, lin, r0)
    sig = np.array([s.sigma for s in problem.free])
    jt = jg * sig
    f = jt.T @ jt
    cov = np.linalg.inv(f + np.eye(len(sig)))
    shares = {s.name: float(cov[i, i]) for i, s in enumerate(problem.free)}
    info = None
    names = [s.name for s in problem.free]
    cols = [jt]
    if look.correction is not None and lin.grid_e is not None:
        jc = _grid_jacobian(problem, look, lin)
        per_col = np.asarray(jc.multiply(jc).sum(axis=0)).ravel() * problem.cell_sigma**2
        info = per_col.reshape(-1, 3).sum(axis=1)
        if not problem.map_mean_fixed:
            # The map's mean ln-correction per channel (every free cell at once), with the prior σ of one cell.
            free = problem._cell_free()
            chan = np.tile(np.arange(3), len(free) // 3)[free]
            mean_cols = np.stack([np.asarray(jc[:, chan == c].sum(axis=1)).ravel() for c in range(3)], axis=1)
            cols.append(mean_cols * problem.cell_sigma)
            names += [f"map_mean_{ch}" for ch in "rgb"]
    ja = np.concatenate(cols, axis=1)
    return shares, info, (ja.T @ ja, names)


#: Most Levenberg–Marquardt iterations of one step on the surrogate.
STEP_ITERATIONS = 25


def _jacobian(problem: Problem, look: Look, lin: Linearisation, r: np.ndarray, cells: bool) -> sp.csr_matrix:
    """∂r/∂x of the data residuals: the global parameters by finite differences, the map cells sparse."""
    blocks = [sp.csr_matrix(_global_jacobian(problem, look, lin, r))]
    if cells:
        blocks.append(_grid_jacobian(problem, look, lin))
    return sp.hstack(blocks, format="csr")


def step(problem: Problem, lin: Linearisation, *, trust: float = TRUST, max_iter: int = STEP_ITERATIONS) -> Look:
    """The minimiser of the surrogate's objective within the ranges and the trust box around θ_k.

    With two independent renders of the light images (``lin.light_images_b``) the data term is ½ r_Aᵀ r_B, the
    surrogate's residuals over each: its expectation is the squared bias alone, so the step is not drawn towards
    looks whose render is less noisy (the errors-in-variables bias of :mod:`.losses`); with one, ½‖r‖².  It is
    minimised by Levenberg–Marquardt (Marquardt 1963) with the Gauss–Newton matrix J̄ᵀJ̄ + J_pᵀJ_p
    (J̄ = (J_A + J_B)/2, J_p the priors'), the exact gradient ½(J_Aᵀ r_B + J_Bᵀ r_A) + J_pᵀ p, and the box handled
    by an active set (a variable on a bound whose gradient pushes outwards is held there); a trial is taken only
    when it lowers the objective."""
    from scipy.sparse.linalg import spsolve

    look0 = lin.look
    pair = (lin, lin.other())
    two = lin.light_images_b is not None
    x0 = problem.pack(look0)
    free = problem.free
    lo = np.array([s.lo for s in free], np.float64)
    hi = np.array([s.hi for s in free], np.float64)
    # The box binds what the surrogate models to first order only: the albedos (ln units) and the haze (its σ
    # per TRUST); the lights it renders exactly are free within their ranges.
    xg = x0[: len(free)]
    width = np.array(
        [
            trust if s.group in ("leaves", "ground") else trust / TRUST * s.sigma if s.group == "haze" else np.inf
            for s in free
        ]
    )
    lo = np.maximum(lo, xg - width)
    hi = np.minimum(hi, xg + width)
    nc = len(x0) - len(free)
    if nc:
        xc = x0[len(free) :]
        lo = np.r_[lo, np.maximum(xc - trust, -3.0)]
        hi = np.r_[hi, np.minimum(xc + trust, 3.0)]
    x = np.clip(x0, lo, hi)
    if not len(x):
        return problem.unpack(x, look0)

    def objective(x: np.ndarray) -> tuple[float, Look, np.ndarray, np.ndarray, np.ndarray]:
        look = problem.unpack(x, look0)
        ra = problem.data_residuals(problem.predict(look, pair[0]))
        rb = problem.data_residuals(problem.predict(look, pair[1])) if two else ra
        p = problem.prior_residuals(look)
        return 0.5 * float(ra @ rb) + 0.5 * float(p @ p), look, ra, rb, p

    f, look, ra, rb, p = objective(x)
    damping = 1e-3
    span = np.maximum(hi - lo, 1e-12)
    for _ in range(max_iter):
        ja = _jacobian(problem, look, pair[0], ra, bool(nc))
        jb = _jacobian(problem, look, pair[1], rb, bool(nc)) if two else ja
        jp = prior_jacobian(problem, look)
        g = 0.5 * (ja.T @ rb + jb.T @ ra) + jp.T @ p
        jm = 0.5 * (ja + jb)
        h = (jm.T @ jm + jp.T @ jp).tocsc()
        diag = np.maximum(h.diagonal(), 1e-12)
        held = ((x <= lo + 1e-12 * span) & (g > 0)) | ((x >= hi - 1e-12 * span) & (g < 0))
        act = np.flatnonzero(~held)
        if not len(act):
            break
        h_act = h[act][:, act]
        improved = False
        for _try in range(12):
            a = h_act + sp.diags(damping * diag[act])
            delta = np.zeros_like(x)
            delta[act] = -np.atleast_1d(spsolve(a.tocsc(), g[act]))
            trial = np.clip(x + delta, lo, hi)
            f_new, look_new, ra_new, rb_new, p_new = objective(trial)
            if f_new < f:
                improved = True
                done = f - f_new <= 1e-7 * max(abs(f), 1e-12) or np.max(np.abs(trial - x) / span) < 1e-7
                x, f, look, ra, rb, p = trial, f_new, look_new, ra_new, rb_new, p_new
                damping = max(damping / 3.0, 1e-9)
                break
            damping *= 4.0
        if not improved or done:
            break
    return look
