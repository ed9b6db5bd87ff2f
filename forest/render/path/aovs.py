"""Comp AOVs of a frame: light groups, first-hit normal, world position, albedo and motion vectors.

``[render] aovs`` names the layers written beside the beauty (:data:`forest.config.schema.AOV_NAMES`);
each comes from the traversal that made the beauty, so they line up with it pixel for pixel:

* **lightgroups** — the beauty split by where its light came from (:meth:`.integrator.PathKernel.sample`
  with ``groups``): every term the path estimator adds to a path's radiance L — an emission hit
  β·w_b·L_k(ω), a next-event estimate β·w_l·f·L_k(ω_l)·V/p_L, the haze's in-scattering
  β·(1 − T)·J(d) — goes to exactly one group, ``sun`` or ``sky`` for light k
  (:func:`.emitters.light_group`) and ``haze`` for the in-scattered light (its ambient and its
  sun-phase term alike).  Per pixel, group g is (Σ over the frame's samples of L_g) / (number of
  samples), the beauty's own estimator, so Σ_g group_g = beauty up to float rounding (not noise).
  :data:`GROUPS` are always written (a group the scene lacks is zero).  They are the undenoised
  sums: with ``[render] denoise`` the beauty is denoised and the groups are not.
* **N** — the first-hit shading normal in world space, turned toward the camera (the denoiser's
  normal guide): n̄ / |n̄| with n̄ the mean over the pixel's camera samples that hit a surface;
  0 where only sky is seen.
* **albedo** — the first-hit albedo R + T (the denoiser's albedo guide): the mean over the pixel's
  camera samples; where a sample saw the sky it counts the sky's radiance clamped to 1 (Open Image
  Denoise's convention for the guides).
* **P** — the world position (metres, Y up) of the first opaque hit of the ray through the pixel
  centre (the ray of ``depth.Z``: texels of α ≥ 0.5 count as opaque), 0 where nothing is hit.
* **motion** — forward motion vectors in pixels: where the point seen at the pixel centre at
  frame f lies on screen at f + ½ minus where it lay at f − ½ (one frame interval, centred on the
  frame, so a compositor's vector blur with its shutter reproduces the render's), u to the right
  and v *up* (Nuke's ``forward.u`` / ``forward.v``).  The point moves with the camera and, on a
  tree, with the tree's wind sway (:func:`forest.wind.tree_matrices`): x(t) = M(t)·M(f)⁻¹·x(f).
  The terrain and the merged far-level trees (world-space meshes: no per-tree row) move with the
  camera only; a pixel that sees the sky is a point at infinity along its ray (camera rotation
  only).  A still (no camera keys, no wind) gives 0.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ...camera import camera_at
from ...imaging import camera_matrices
from ...wind import tree_matrices
from .frame import PassResult

if TYPE_CHECKING:
    from ...config import Config
    from ...instances import InstanceSet

#: The light groups written with ``lightgroups`` (EXR layers ``lightgroup.<name>.R/G/B``).
GROUPS = ("sun", "sky", "haze")
#: The EXR layer of the motion vectors.
MOTION_LAYER = "forward"


class GroupSums:
    """Per-pixel sums of the light groups over a frame's passes (the beauty's samples, the same count)."""

    def __init__(self, pixels: int):
        self.pixels = int(pixels)
        self.sums = {g: np.zeros((self.pixels, 3)) for g in GROUPS}
        self.samples = 0

    def add(self, p: PassResult) -> None:
        """Add one pass's group sums (a pass without them adds its samples to the count only: zero light)."""
        for g, v in (p.groups or {}).items():
            self.sums[g] += v
        self.samples += p.spp

    def images(self, height: int, width: int) -> dict[str, np.ndarray]:
        """``lightgroup.<g>`` → (H, W, 3) float32 mean over the samples."""
        n = max(self.samples, 1)
        return {f"lightgroup.{g}": (v / n).reshape(height, width, 3).astype(np.float32) for g, v in self.sums.items()}


def unit_normals(normal: np.ndarray) -> np.ndarray:
    """n̄ / |n̄| per pixel ((H, W, 3)), 0 where |n̄| = 0."""
    n = np.asarray(normal, np.float64)
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    return np.where(length > 0.0, n / np.where(length > 0.0, length, 1.0), 0.0).astype(np.float32)


def _project(world_to_ndc: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Homogeneous points (N, 4) → (NDC u, v (N, 2), in front of the camera (N,))."""
    m = world_to_ndc

    def row(k: int) -> np.ndarray:  # one output coordinate from the columns (a (N, 4) @ (4, 4) is slower)
        return x[:, 0] * m[k, 0] + x[:, 1] * m[k, 1] + x[:, 2] * m[k, 2] + x[:, 3] * m[k, 3]

    w = row(3)
    front = w > 1e-9
    inv_w = 1.0 / np.where(front, w, 1.0)
    return np.stack([row(0) * inv_w, row(1) * inv_w], axis=1), front


def motion_vectors(
    config: Config,
    instances: InstanceSet,
    frame: float,
    position: np.ndarray,
    row: np.ndarray,
) -> np.ndarray:
    """Forward motion vectors (H, W, 2) float32 in pixels, u right and v up (see the module docstring).

    ``position`` (H, W, 3) and ``row`` (H, W; tree index < N, N world-space parts, −1 nothing) are the
    pixel-centre hits at frame ``frame``'s centre pose (:meth:`.frame.PathScene.layers`).
    """
    cam, wind = config.camera, config.wind
    h, w = row.shape
    near, far = float(cam.near), float(cam.far)

    def matrices(t: float) -> np.ndarray:
        s = camera_at(cam, t)
        return camera_matrices(s.position, s.target, s.up, s.fov, w, h, near=near, far=far).world_to_ndc

    m_c, m_0, m_1 = matrices(frame), matrices(frame - 0.5), matrices(frame + 0.5)
    rows = np.asarray(row, np.int64).ravel()
    hit = rows >= 0
    x0 = np.zeros((h * w, 4))
    x0[:, :3] = np.asarray(position, np.float64).reshape(-1, 3)
    x0[:, 3] = 1.0
    # Sky: the pixel-centre ray's direction as a point at infinity (the far plane's point minus the eye).
    if not hit.all():
        sky = np.flatnonzero(~hit)
        ys, xs = np.divmod(sky, w)
        ndc = np.stack([(xs + 0.5) / w, (ys + 0.5) / h, np.ones(len(sky)), np.ones(len(sky))], axis=1)
        far_pts = ndc @ np.linalg.inv(m_c).T
        eye = camera_at(cam, frame).position
        x0[sky, :3] = far_pts[:, :3] / far_pts[:, 3:4] - np.asarray(eye, np.float64)
        x0[sky, 3] = 0.0
    x1 = x0.copy()
    n = len(instances)
    trees = hit & (rows < n)
    if wind.strength > 0 and trees.any():
        fps = float(cam.fps)
        seen = np.zeros(n, bool)
        seen[rows[trees]] = True
        sub = instances.subset(np.flatnonzero(seen))  # the trees seen, without sorting the pixels
        inverse = (np.cumsum(seen) - 1)[rows[trees]]
        to_local = np.linalg.inv(tree_matrices(sub, frame / fps, wind))
        x = x0[trees]
        for out_x, t in ((x0, frame - 0.5), (x1, frame + 0.5)):
            a = tree_matrices(sub, t / fps, wind) @ to_local  # per tree: M(t)·M(f)⁻¹, affine
            moved = np.empty((len(x), 3))
            for i in range(3):  # gathered one coefficient at a time: no (pixels, 4, 4) array
                moved[:, i] = a[:, i, 3][inverse]
                for j in range(3):
                    moved[:, i] += a[:, i, j][inverse] * x[:, j]
            out_x[trees, :3] = moved
    uv0, f0 = _project(m_0, x0)
    uv1, f1 = _project(m_1, x1)
    out = np.zeros((h * w, 2))
    ok = f0 & f1
    out[ok, 0] = (uv1[ok, 0] - uv0[ok, 0]) * w
    out[ok, 1] = -(uv1[ok, 1] - uv0[ok, 1]) * h  # NDC v runs down the image; the vectors' v runs up
    return out.reshape(h, w, 2).astype(np.float32)


def frame_aovs(
    names: Any,
    *,
    config: Config,
    instances: InstanceSet,
    frame: float,
    normal: np.ndarray | None,
    albedo: np.ndarray | None,
    layers: dict[str, np.ndarray],
    groups: GroupSums | None = None,
) -> dict[str, np.ndarray]:
    """The EXR layers of ``[render] aovs`` = ``names`` for one frame: layer name → (H, W, channels) float32.

    ``normal`` / ``albedo``: the frame's first-hit guides (:class:`~forest.render.output.FrameImage`);
    ``layers``: the pixel-centre layers with ``position`` and ``row``; ``groups``: the light-group sums
    of the beauty's passes (None: no light groups, e.g. ``scalar_rgb``).
    """
    wanted = set(names)
    out: dict[str, np.ndarray] = {}
    if "N" in wanted and normal is not None:
        out["N"] = unit_normals(normal)
    if "P" in wanted and "position" in layers:
        out["P"] = np.asarray(layers["position"], np.float32)
    if "albedo" in wanted and albedo is not None:
        out["albedo"] = np.asarray(albedo, np.float32)
    if "motion" in wanted and "position" in layers:
        out[MOTION_LAYER] = motion_vectors(config, instances, frame, layers["position"], layers["row"])
    if "lightgroups" in wanted and groups is not None:
        h, w = np.asarray(layers["depth"]).shape
        out.update(groups.images(h, w))
    return out
