"""The data terms of a fit, as residual vectors r whose loss is ½‖r‖² (the priors add theirs in :mod:`.solve`).

**aligned** — the reference is a plate or render from the same camera: one
residual per block b of :data:`BLOCK` × :data:`BLOCK` pixels and channel c,

    r_bc = √w_bc · ln((⟨Q⟩_bc + κ_c) / (⟨P⟩_bc + κ_c)) / τ,

with Q the predicted photo (:mod:`.image_model`), P the reference, κ_c a tenth of
the median of P's channel c over the frame (so the darkest blocks do not dominate),
and τ = :data:`PIXEL_TOLERANCE` the *relative* error one residual unit stands for —
whatever the image's units, so a dim forest and a bright one weigh their data
against the priors alike.  w_bc = 1/(1 + v_bc/τ²) makes each residual's unit the
block's whole error, v_bc the relative Monte-Carlo variance of the fit's render of
the block (:meth:`PixelLoss.set_noise`, measured from two independent renders of
the same look) added to τ²: weighted least squares with weights ∝ 1/σ² is the
minimum-variance estimator (Aitken 1935), so silhouettes and shadow edges, noisy at
low spp, count for what they can tell, and the priors are weighed against data of
their true precision.

Why logarithms and blocks: a least-squares fit to a Monte-Carlo render is biased
towards looks whose render is less noisy, E‖Q − P‖² = ‖E Q − P‖² + Σ Var Q — the
errors-in-variables attenuation (Fuller 1987, *Measurement Error Models*, §1.1).
In linear units Var Q grows with the square of what the look makes of a pixel, so
the variance term pulls every albedo and light towards black (on a top-down forest
at 8 spp it pulled the blue channel down by a third and the sky towards orange).
A path tracer's *relative* noise does not depend on an albedo multiplier or a
light's scale (every path's contribution scales alike), so in logarithms the
variance term is, to first order, the same constant for every look and no longer
moves the minimum.  Means over b pixels shrink the remaining (second-order) term by
b; the held-out judgement removes it altogether (:meth:`.solve.Problem.objective`:
the product of two independent renders' residuals, whose expectation is the squared
bias alone).

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
from typing import TYPE_CHECKING

import numpy as np

from .colour import luminance
from .reference import Reference
from .regions import Region, region_means

if TYPE_CHECKING:
    import scipy.sparse as sp

PIXEL_TOLERANCE = 0.02
#: κ_c of the aligned residuals, as a share of the reference channel's median block.
KAPPA = 0.1
#: Side of the square pixel blocks the aligned loss compares.
BLOCK = 2
LOG_TOLERANCE = 0.05


def log_colour(rgb: np.ndarray) -> np.ndarray:
    """(ln Y, ln r/g, ln b/g) of linear colours (..., 3), floored at 10⁻⁶."""
    c = np.maximum(np.asarray(rgb, np.float64), 1e-6)
    y = np.maximum(luminance(c), 1e-6)
    return np.stack([np.log(y), np.log(c[..., 0] / c[..., 1]), np.log(c[..., 2] / c[..., 1])], axis=-1)


def block_operator(height: int, width: int, block: int) -> sp.csr_matrix:
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


@dataclass
class PixelLoss:
    """Relative (logarithmic), noise-weighted block residuals against a same-camera reference."""

    reference: Reference
    weight: np.ndarray = field(init=False)  # (blocks·3,) w_bc

    block: int = BLOCK

    def __post_init__(self) -> None:
        h, w_ = self.reference.rgb.shape[:2]
        self.blocks = block_operator(h, w_, self.block)  # (blocks·3) × (pixels·3): block means
        self.target = self.blocks @ self.reference.rgb.astype(np.float64).ravel()
        pw = np.repeat(self.reference.weight.astype(np.float64)[..., None], 3, axis=2).ravel()
        base = self.blocks @ pw  # the reference's own weights (a grey mask), block means
        t = self.target.reshape(-1, 3)
        valid = base.reshape(-1, 3)[:, 0] > 0
        med = np.median(t[valid], axis=0) if valid.any() else np.ones(3)
        self.kappa = np.tile(KAPPA * np.maximum(med, 0.0) + 1e-9, len(t))
        self.log_target = np.log(np.maximum(self.target, 0.0) + self.kappa)
        self.base = base
        self.weight = base.copy()
        self.group_names: list[str] = ["whole frame"]
        self.group_of = np.zeros(len(self.target), np.int64)

    def set_groups(self, labels: np.ndarray, names: dict[int, str]) -> None:
        """Name each residual by the region (``labels`` (H, W), ``names`` label → name) most of its block shows:
        which observation pulls a parameter where it ends (:meth:`.fit.Fitter.driver`)."""
        keys = sorted(names)
        votes = np.stack(
            [
                self.blocks @ np.repeat((np.asarray(labels) == k).astype(np.float64)[..., None], 3, axis=2).ravel()
                for k in keys
            ]
        )
        self.group_names = [names[k] for k in keys]
        self.group_of = np.argmax(votes, axis=0)

    def set_noise(self, variance: np.ndarray) -> None:
        """Weigh each value down by its render's relative noise (module docstring; ``variance`` per pixel and
        channel, a block mean's is their mean over the block's b pixels / b); the weights' sum stays the base's."""
        var_b = (self.blocks @ np.asarray(variance, np.float64).ravel()) / self.block**2
        v = var_b / (np.maximum(self.target, 0.0) + self.kappa) ** 2
        pos = v[(v > 0) & (self.base > 0)]
        if not pos.size:
            return
        self.weight = self.base / (1.0 + v / PIXEL_TOLERANCE**2)

    def mask(self, keep: np.ndarray) -> None:
        """Drop the blocks with any pixel where ``keep`` (H, W) is false."""
        k = np.repeat(np.asarray(keep, np.float64)[..., None], 3, axis=2).ravel()
        whole = (self.blocks @ k) >= 1.0 - 1e-9
        self.weight = np.where(whole, self.weight, 0.0)
        self.base = np.where(whole, self.base, 0.0)

    def residuals(self, image: np.ndarray) -> np.ndarray:
        """r = √w (ln(⟨Q⟩ + κ) − ln(⟨P⟩ + κ))/τ per block and channel, of the block means ⟨Q⟩ of linear ``image``."""
        q = self.blocks @ np.asarray(image, np.float64).ravel()
        return np.sqrt(self.weight) * (np.log(np.maximum(q, 0.0) + self.kappa) - self.log_target) / PIXEL_TOLERANCE

    def project(self, jac: sp.csr_matrix, image: np.ndarray) -> sp.csr_matrix:
        """∂r/∂x from ∂Q/∂x per pixel value (a sparse (pixels·3) × n matrix) at the photo ``image``:
        √w/(τ (⟨Q⟩ + κ)) · B · J."""
        import scipy.sparse as sp

        q = self.blocks @ np.asarray(image, np.float64).ravel()
        scale = np.sqrt(self.weight) / (PIXEL_TOLERANCE * (np.maximum(q, 0.0) + self.kappa))
        return sp.diags(scale) @ (self.blocks @ jac)

    def value(self, image: np.ndarray) -> float:
        """½‖r‖² of ``image``."""
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
        comps = ("luminance", "red/green", "blue/green")
        self.group_names = [f"{n} {c}" for n in self.names for c in comps]
        self.group_of = np.arange(3 * len(self.names))

    def means(self, image: np.ndarray) -> np.ndarray:
        """(K + 1, 3) mean linear colours of the image's regions, the whole frame last."""
        m = region_means(image, self._render_masks)
        whole = np.asarray(image, np.float64).reshape(-1, 3).mean(axis=0)[None]
        return np.concatenate([m, whole]) if len(m) else whole

    def residuals(self, image: np.ndarray) -> np.ndarray:
        """(ln Y, ln r/g, ln b/g) of the region means minus the photo's, over :data:`LOG_TOLERANCE`, flattened."""
        return ((log_colour(self.means(image)) - self.target) / LOG_TOLERANCE).ravel()

    def delta_e(self, image: np.ndarray) -> dict[str, float]:
        """CIEDE2000 between the image's and the photo's mean colour of each region (and the whole frame)."""
        from .colour import delta_e2000

        de = delta_e2000(np.maximum(self.means(image), 0.0), self.target_rgb)
        return {n: float(d) for n, d in zip(self.names, np.atleast_1d(de))}

    def value(self, image: np.ndarray) -> float:
        """½‖r‖² of ``image``."""
        r = self.residuals(image)
        return 0.5 * float(r @ r)
