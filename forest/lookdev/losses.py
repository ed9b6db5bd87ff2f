"""The data terms of a fit, as residual vectors r whose loss is ½‖r‖² (the priors add theirs in :mod:`.solve`).

**aligned** — the reference is a plate or render from the same camera: one
residual per block b of :data:`BLOCK` × :data:`BLOCK` pixels and channel c,

    r_bc = √w_bc · (⟨Q⟩_bc − ⟨R⟩_bc) / τ,        w_bc = ρ_b / (1 + ρ_b σ²_bc / (β · median ρσ²)),

with Q the predicted photo (:mod:`.image_model`), ρ_p = 1/(Ȳ_p + κ)² a
*relative* weight (Ȳ the reference luminance box-blurred over 3×3 pixels, κ a
tenth of its median), normalised to mean 1, and τ = :data:`PIXEL_TOLERANCE`
the relative error one residual unit stands for.  σ²_pc is the Monte-Carlo
variance of the render (:meth:`PixelLoss.set_noise`, measured from two
independent renders of the same look): weighted least squares with weights
∝ 1/σ² is the minimum-variance estimator (Aitken 1935), so silhouettes and
shadow edges, noisy at low spp, are weighed down where their noise dominates
(β = :data:`NOISE_BALANCE`).

Why blocks: a least-squares fit to a Monte-Carlo render is biased towards looks
whose render is less noisy, E‖Q − R‖² = ‖E Q − R‖² + Σ Var Q — the
errors-in-variables attenuation (Fuller 1987, *Measurement Error Models*, §1.1):
on a 48×36 test at 8 spp it put the sun at 60 % of the truth, its variance
term outweighing the bias of the right answer.  Means over b pixels divide the
variance term by b at the price of detail finer than a block; the held-out
judgement removes it altogether (:meth:`.solve.Problem.objective`: the product
of two independent renders' residuals, whose expectation is the squared bias alone).

**statistics** — an unrelated photo: per region k (:mod:`.regions`: sky high
and low, canopy and ground, each lit and shadowed) and for the whole frame,
with m_k the region's mean linear colour,

    r_k = ( ln(Y(m_k)/Y(p_k)),  ln(r/g)_m − ln(r/g)_p,  ln(b/g)_m − ln(b/g)_p ) / τ_ln,

its luminance and two chromaticity ratios in logarithms, τ_ln =
:data:`LOG_TOLERANCE`: 5 % in luminance is about two CIELAB lightness steps at
mid-grey (ΔL* ≈ 2.2) — as close as the mean colours of another place's sky,
foliage and ground can be asked to come, so the priors keep their say where
the photo's statistics could be met by trading parameters (a warm sun against
a cool white balance).  Logarithms rather than CIELAB differences because a
render can start far from the photo — a forest interior 9 EV too dark — where
CIELAB's slope vanishes (L* = 903.3·Y near black) and the data would look
uninformative; in logarithms exposure moves every residual at the same rate
wherever it starts.  At the match the two agree: equal means, equal CIELAB.
Mean colours, not pixels: where an unrelated photo puts its trees says nothing
about the scene's, but what colour its sky, its sunlit and shadowed foliage
and its ground are, does.  The report gives CIEDE2000 between the means.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .colour import luminance
from .reference import Reference
from .regions import Region, region_means

PIXEL_TOLERANCE = 0.02
#: Side of the square pixel blocks the aligned loss compares.
BLOCK = 2
LOG_TOLERANCE = 0.05
NOISE_BALANCE = 0.1


def log_colour(rgb: np.ndarray) -> np.ndarray:
    """(ln Y, ln r/g, ln b/g) of linear colours (..., 3), floored at 10⁻⁶."""
    c = np.maximum(np.asarray(rgb, np.float64), 1e-6)
    y = np.maximum(luminance(c), 1e-6)
    return np.stack([np.log(y), np.log(c[..., 0] / c[..., 1]), np.log(c[..., 2] / c[..., 1])], axis=-1)


def block_operator(height: int, width: int, block: int):
    """The sparse (blocks·3) × (H·W·3) matrix of block means over ``block`` × ``block`` pixels, per channel (a
    last row or column of partial blocks is dropped)."""
    import scipy.sparse as sp

    bh, bw = max(height // block, 1), max(width // block, 1)
    b = min(block, height, width)
    ys, xs = np.mgrid[0 : bh * b, 0 : bw * b]
    pix = (ys * width + xs).ravel()
    blk = ((ys // b) * bw + xs // b).ravel()
    rows = (blk[:, None] * 3 + np.arange(3)).ravel()
    cols = (pix[:, None] * 3 + np.arange(3)).ravel()
    vals = np.full(len(rows), 1.0 / (b * b))
    return sp.csr_matrix((vals, (rows, cols)), shape=(bh * bw * 3, height * width * 3))


def _box3(a: np.ndarray) -> np.ndarray:
    from scipy.ndimage import uniform_filter

    return uniform_filter(a, size=3, mode="nearest")


@dataclass
class PixelLoss:
    """Relative, noise-weighted pixel residuals against a same-camera reference."""

    reference: Reference
    weight: np.ndarray = field(init=False)  # (H, W, 3) w_pc

    block: int = BLOCK

    def __post_init__(self) -> None:
        h, w_ = self.reference.rgb.shape[:2]
        self.blocks = block_operator(h, w_, self.block)  # (blocks·3) × (pixels·3): block means
        y = _box3(luminance(self.reference.rgb)).astype(np.float64)
        w = self.reference.weight.astype(np.float64)
        kappa = 0.1 * float(np.median(y[w > 0])) + 1e-4
        rho = w / (y + kappa) ** 2
        rho_b = self.blocks @ np.repeat(rho[..., None], 3, axis=2).ravel()
        rho_b /= max(float(rho_b[rho_b > 0].mean()), 1e-30)
        self.rho = rho_b
        self.weight = rho_b.copy()
        self.target = self.blocks @ self.reference.rgb.astype(np.float64).ravel()

    def set_noise(self, variance: np.ndarray) -> None:
        """Weigh each value by its render noise (module docstring; ``variance`` per pixel and channel, a block
        mean's is their mean over the block's b pixels / b); the mean weight stays 1."""
        rho = self.rho
        var_b = (self.blocks @ np.asarray(variance, np.float64).ravel()) / self.block**2
        v = rho * var_b
        pos = v[(v > 0) & (rho > 0)]
        if not pos.size:
            return
        w = rho / (1.0 + v / (NOISE_BALANCE * float(np.median(pos))))
        self.weight = w * (rho.sum() / max(float(w.sum()), 1e-30))

    def mask(self, keep: np.ndarray) -> None:
        """Drop the blocks with any pixel where ``keep`` (H, W) is false."""
        k = np.repeat(np.asarray(keep, np.float64)[..., None], 3, axis=2).ravel()
        whole = (self.blocks @ k) >= 1.0 - 1e-9
        self.weight = np.where(whole, self.weight, 0.0)
        self.rho = np.where(whole, self.rho, 0.0)

    def residuals(self, image: np.ndarray) -> np.ndarray:
        q = self.blocks @ np.asarray(image, np.float64).ravel()
        return np.sqrt(self.weight) * (q - self.target) / PIXEL_TOLERANCE

    def project(self, jac):
        """∂r/∂x from ∂Q/∂x per pixel value (a sparse (pixels·3) × n matrix): √w/τ · B · J."""
        import scipy.sparse as sp

        return sp.diags(np.sqrt(self.weight) / PIXEL_TOLERANCE) @ (self.blocks @ jac)

    def value(self, image: np.ndarray) -> float:
        r = self.residuals(image)
        return 0.5 * float(r @ r)


@dataclass
class RegionLoss:
    """CIELAB differences of region mean colours against an unrelated photo."""

    photo: np.ndarray  # (H, W, 3) linear
    regions: list[Region]

    def __post_init__(self) -> None:
        self.names = [r.name for r in self.regions] + ["whole image"]
        self._render_masks = [r.render for r in self.regions]
        self._photo_masks = [r.photo for r in self.regions]
        valid_photo = np.ones(self.photo.shape[:2], bool).ravel()
        photo_means = region_means(self.photo, self._photo_masks)
        whole = self.photo.reshape(-1, 3)[valid_photo].mean(axis=0)[None]
        self.target_rgb = np.concatenate([photo_means, whole]) if len(photo_means) else whole
        self.target = log_colour(self.target_rgb)

    def means(self, image: np.ndarray) -> np.ndarray:
        """(K + 1, 3) mean linear colours of the image's regions, the whole frame last."""
        m = region_means(image, self._render_masks)
        whole = np.asarray(image, np.float64).reshape(-1, 3).mean(axis=0)[None]
        return np.concatenate([m, whole]) if len(m) else whole

    def residuals(self, image: np.ndarray) -> np.ndarray:
        return ((log_colour(self.means(image)) - self.target) / LOG_TOLERANCE).ravel()

    def delta_e(self, image: np.ndarray) -> dict[str, float]:
        """CIEDE2000 between the image's and the photo's mean colour of each region (and the whole frame)."""
        from .colour import delta_e2000

        de = delta_e2000(np.maximum(self.means(image), 0.0), self.target_rgb)
        return {n: float(d) for n, d in zip(self.names, np.atleast_1d(de))}

    def value(self, image: np.ndarray) -> float:
        r = self.residuals(image)
        return 0.5 * float(r @ r)
