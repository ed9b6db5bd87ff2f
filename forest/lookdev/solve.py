"""One Gauss–Newton step of the fit: a surrogate of the render around the current look, solved exactly.

Around the look θ_k the render is modelled as

    R(θ) = [Σ_l s_l(θ) ⊙ U_l] ⊙ exp( Σ_a e_a ⊙ (ln m_a(θ) − ln m_a(θ_k)) + Σ_j e_j ⊙ (c_j − c_j,k) )

* U_l — the image of light l at unit scale, rendered at θ_k: the path tracer
  is linear in each light's RGB scale s_l, so the light part is exact;
* e_a = (∂I/∂ln m_a) / I — the elasticity of each pixel and channel to an
  albedo multiplier m_a (a species' leaves, the ground), measured by forward-mode
  path replay; first order in ln m, which is exact for singly scattered light
  and close for the rest;
* e_j — the same for the colour map's ln-correction cells c_j (aligned mode),
  one value per pixel and class of cells (:mod:`.correction`): a sparse,
  per-channel Jacobian — channel c of the image depends on channel c of the
  cells only, and each pixel on at most four cells — so the system stays
  (pixels·3) × (cells·3) with ≤ 9 non-zeros a row instead of a dense matrix
  and its eigendecomposition (at ``--grid 64``: 12 288 columns).

Through the image model (:mod:`.image_model`: exposure, white balance,
clipping, and a change of haze) and the data residuals (:mod:`.losses`), plus the priors — (θ − μ)/σ
for every global parameter, c/σ_c and the smoothness differences of the map
cells, and the constraint that species' relative leaf multipliers sum to
zero — the step minimises ½‖r‖² with ``scipy.optimize.least_squares``
(trust-region reflective, Branch, Coleman & Li 1999) inside the parameters'
ranges intersected with a trust box around θ_k for the linearised albedo
parameters.  The Jacobian of the global parameters is taken by finite
differences of the surrogate (a few dozen cheap evaluations), the map cells'
analytically and sparse.

**What the reference determines.**  At the first step the data's Fisher
information F = J̃ᵀJ̃ of the global parameters (J̃ in prior units, columns
scaled by σ) gives the posterior covariance C = (F + I)⁻¹: C_ii is the share of
a parameter's prior variance left after the data.  A parameter whose share
stays above :data:`UNDETERMINED` (the reference narrows it by less than 10 %) is
held at its start value and reported as undetermined, rather than traded
against the parameters it is confounded with; the others are fitted with
their priors.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from .image_model import ImageModel
from .look import camera_gain, ground_tint, haze_colour, leaf_tints, lights
from .losses import PixelLoss, RegionLoss
from .params import Look, Spec, Start

UNDETERMINED = 0.9
#: Prior σ of a colour-map ln-correction cell.
CELL_SIGMA = 0.5
#: Prior σ of the ln-correction's change across the whole map: a difference between neighbouring cells of an
#: n-cell side has σ = CELL_SPAN / (n − 1) (a smooth field whose slope is the same at any grid), at least
#: :data:`CELL_SMOOTH_MIN`.
CELL_SPAN = 1.0
CELL_SMOOTH_MIN = 0.02


def cell_smooth(cells: tuple[int, int]) -> float:
    """σ of a difference between neighbouring correction cells (see :data:`CELL_SPAN`)."""
    return max(CELL_SPAN / max(max(cells) - 1, 1), CELL_SMOOTH_MIN)


#: σ of the sum of species' relative leaf ln-multipliers (a soft equality constraint).
SUM_SIGMA = 0.01
#: Largest change of a linearised ln-albedo in one step (the trust box), at the start.
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

    @property
    def free(self) -> list[Spec]:
        return [s for s in self.specs if s.name not in self.held]

    # -- the surrogate --------------------------------------------------------------------
    def light_scales(self, look: Look) -> dict[str, np.ndarray]:
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
            out["haze_colour"] = haze_colour(look, self.start, lt)
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

    def albedo_exponent(self, look: Look, at: Look, lin: Linearisation, shape: tuple) -> np.ndarray:
        """Σ_a e_a ⊙ (ln m_a(look) − ln m_a(at)) (+ the map cells'): the first-order ln-change of the image from
        the albedos of ``at`` to those of ``look``, with ``lin``'s elasticities; (H, W, 3), clipped to ±20."""
        expo = np.zeros(shape)
        if lin.leaf_e is not None:
            d = np.log(leaf_tints(look, self.n_species)) - np.log(leaf_tints(at, self.n_species))
            expo += np.einsum("shwc,sc->hwc", lin.leaf_e, d)
        if lin.ground_e is not None:
            expo += lin.ground_e * (np.log(ground_tint(look)) - np.log(ground_tint(at)))
        if lin.grid_e is not None and look.correction is not None and at.correction is not None:
            dc = (look.correction - at.correction).reshape(-1, 3)
            cells = lin.grid_cells
            assert cells is not None
            h, w = shape[:2]
            for k in range(9):
                idx = cells[:, k]
                ok = idx >= 0
                delta = np.zeros((h * w, 3))
                delta[ok] = dc[idx[ok]]
                expo += lin.grid_e[k] * delta.reshape(h, w, 3)
        return np.clip(expo, -20.0, 20.0)

    def photo_model(self, look: Look, render: np.ndarray, rendered_at: Look | None = None) -> np.ndarray:
        """The photo predicted from a render at ``look`` — or, in the surrogate, from a render at
        ``rendered_at`` moved to ``look``'s haze (:mod:`.image_model`)."""
        d_sigma = 0.0
        if rendered_at is not None:
            d_sigma = look.get("haze", self.start.haze) - rendered_at.get("haze", self.start.haze)
        lt = lights(look, self.start)
        return self.image.apply(
            render, gain=camera_gain(look), d_sigma=d_sigma, airlight=haze_colour(look, self.start, lt)
        )

    def predict(self, look: Look, lin: Linearisation) -> np.ndarray:
        """The surrogate's photo at ``look``."""
        return self.photo_model(look, self.render_model(look, lin), lin.look)

    # -- residuals --------------------------------------------------------------------------
    def prior_residuals(self, look: Look) -> np.ndarray:
        parts = [np.array([(look.values[s.name] - s.mean) / s.sigma for s in self.free])]
        rel = [s.name for s in self.free if s.name.startswith("leaf") and not s.name.startswith("leaves")]
        if rel:
            for ch in "rgb":
                parts.append(np.array([sum(look.get(f"leaf{s}_{ch}") for s in range(self.n_species)) / SUM_SIGMA]))
        if look.correction is not None and self.cells is not None:
            c = look.correction.reshape(-1, 3)
            parts.append((c / CELL_SIGMA).ravel())
            parts.append((smoothness(self.cells) @ c / cell_smooth(self.cells)).ravel())
        return np.concatenate(parts) if parts else np.zeros(0)

    def data_residuals(self, photo: np.ndarray) -> np.ndarray:
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
        x = [look.values[s.name] for s in self.free]
        if look.correction is not None:
            x += list(look.correction.ravel()[self._cell_free()])
        return np.asarray(x, np.float64)

    def unpack(self, x: np.ndarray, like: Look) -> Look:
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
    for k in range(9):
        idx = lin.grid_cells[:, k]
        ok = idx >= 0
        e = (lin.grid_e[k] * dq).reshape(-1, 3)
        for c in range(3):
            r = pix[ok] * 3 + c
            rows.append(r)
            cols.append(idx[ok] * 3 + c)
            vals.append(e[ok, c])
    n_cells = problem.cells[0] * problem.cells[1]  # type: ignore[index]
    m = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(h * w * 3, n_cells * 3)
    )
    return problem.loss.project(m[:, problem._cell_free()]).tocsr()


def prior_jacobian(problem: Problem, look: Look) -> sp.csr_matrix:
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
        eye = sp.identity(n * 3, format="csr") / CELL_SIGMA
        d3 = sp.kron(smoothness(problem.cells), sp.identity(3), format="csr") / cell_smooth(problem.cells)
        blocks_rows.append(sp.hstack([sp.csr_matrix((n * 3, ng)), eye[:, keep]]))
        blocks_rows.append(sp.hstack([sp.csr_matrix((d3.shape[0], ng)), d3[:, keep]]))
    return sp.vstack(blocks_rows, format="csr")


def undetermined(problem: Problem, look: Look, lin: Linearisation) -> tuple[dict[str, float], np.ndarray | None]:
    """(posterior/prior variance share of each free global parameter, data information per map cell)."""
    r0 = problem.data_residuals(problem.predict(look, lin))
    jg = _global_jacobian(problem, look, lin, r0)
    sig = np.array([s.sigma for s in problem.free])
    jt = jg * sig
    f = jt.T @ jt
    cov = np.linalg.inv(f + np.eye(len(sig)))
    shares = {s.name: float(cov[i, i]) for i, s in enumerate(problem.free)}
    info = None
    if look.correction is not None and lin.grid_e is not None:
        jc = _grid_jacobian(problem, look, lin)
        per_col = np.asarray(jc.multiply(jc).sum(axis=0)).ravel() * CELL_SIGMA**2
        info = per_col.reshape(-1, 3).sum(axis=1)
    return shares, info


def step(problem: Problem, lin: Linearisation, *, trust: float = TRUST, max_nfev: int = 40) -> Look:
    """The minimiser of the surrogate's ½‖r‖² within the ranges and the trust box around θ_k."""
    from scipy.optimize import least_squares

    look0 = lin.look
    x0 = problem.pack(look0)
    free = problem.free
    lo = np.array([s.lo for s in free], np.float64)
    hi = np.array([s.hi for s in free], np.float64)
    linear = np.array([s.group in ("leaves", "ground") for s in free])
    xg = x0[: len(free)]
    lo = np.where(linear, np.maximum(lo, xg - trust), lo)
    hi = np.where(linear, np.minimum(hi, xg + trust), hi)
    nc = len(x0) - len(free)
    if nc:
        xc = x0[len(free) :]
        lo = np.r_[lo, np.maximum(xc - trust, -3.0)]
        hi = np.r_[hi, np.minimum(xc + trust, 3.0)]
    x0 = np.clip(x0, lo, hi)
    cache: dict[bytes, tuple[Look, np.ndarray]] = {}

    def state(x):
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            look = problem.unpack(x, look0)
            r = problem.data_residuals(problem.predict(look, lin))
            cache[key] = (look, r)
        return cache[key]

    def fun(x):
        look, r = state(x)
        return np.concatenate([r, problem.prior_residuals(look)])

    def jac(x):
        look, r = state(x)
        jg = sp.csr_matrix(_global_jacobian(problem, look, lin, r))
        blocks = [jg]
        if nc:
            blocks.append(_grid_jacobian(problem, look, lin))
        data = sp.hstack(blocks, format="csr")
        full = sp.vstack([data, prior_jacobian(problem, look)], format="csr")
        return full if nc else full.toarray()

    scale = np.r_[np.array([s.sigma for s in free]), np.full(nc, CELL_SIGMA)]
    res = least_squares(
        fun,
        x0,
        jac=jac,
        bounds=(lo, hi),
        method="trf",
        tr_solver="lsmr" if nc else "exact",
        x_scale=scale,
        max_nfev=max_nfev,
        xtol=1e-6,
        ftol=1e-6,
    )
    return problem.unpack(res.x, look0)
