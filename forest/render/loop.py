"""One frame loop for both renderers: the recipe of a frame, over a small :class:`Backend`.

The split follows pbrt-v4's ``RayIntegrator`` (``Render`` drives the pixels and
samples, ``Li`` traces a ray) and Mitsuba 3's ``ADIntegrator`` (``render``
drives, ``sample`` traces): the recipe is written once here, and a backend
only poses its scene and traces.  Per frame f (time t = f / fps seconds):

1. every tree gets its level of detail from its distance to the camera at f
   (the Scene's plan, :meth:`forest.scene.Scene.levels`);
2. with ``shutter`` s > 0 the frame averages K = ``[render] subframes``
   sub-frames at f + s·((k + ½)/K − ½) (:func:`forest.camera.subframe_times`),
   each with its own camera — a box filter over the shutter — and a wind pose
   (:meth:`Backend.pose`).  A new wind pose is a new scene build, and the sway
   over a shutter is small: the sub-frames, in time order, share m ≤ K poses
   in runs of near-equal length, each run posed at its mean time
   (:func:`pose_times`), m the fewest poses for which no tree's top in view
   moves between two poses by more than the camera already moves it between
   two sub-frames, or than :data:`POSE_PIXELS`:

       m = clamp(max_i ⌈M_i / max(POSE_PIXELS, S_i)⌉, 1, K)

   with M_i the pixels tree i's top sways between the first and last
   sub-frame (its matrices at both times, projected with the frame's
   camera) and S_i the pixels the camera moves it between two sub-frames
   (its top at the frame's pose, projected by the first and last sub-frames'
   cameras, over K − 1).  Without wind every sub-frame shares one pose; with
   m = K each has its own, as a box filter of the sway would.  The run nearest
   the frame's centre is rendered last (its sub-frame nearest the centre
   last of all), so a pose near the centre's is loaded for step 4; the
   farthest is rendered first, and a backend built for frame f loads that
   pose (:func:`first_pose_time`), so m poses cost m scene builds;
3. each sub-frame traces ⌈spp / K⌉ samples per pixel in passes
   (:meth:`Backend.passes`, :meth:`Backend.samples`), seeded
   ``seed · 1 000 003 + round(1000 f) · 997 + 101 k`` for sub-frame k
   (:func:`frame_seed`), so a frame's image depends only on the config and
   the frame number; the running mean is handed to ``on_pass`` after every
   pass.  The beauty is Σ (samples' radiance) / Σ samples.  With adaptive
   sampling (:mod:`forest.render.adaptive`) a pass carries per-pixel sample
   counts n_p: each sub-frame's image is its per-pixel mean Σ L / n_p, and the
   frame the mean of its sub-frames' images (the box filter over the shutter
   stays even where a pixel stopped earlier in one sub-frame than another);
4. the frame's first hits — per-sample coverage (alpha), the per-tree and
   per-species Cryptomattes (:mod:`forest.render.coverage`) and the
   denoiser's guides (albedo, normal) — come with the beauty's samples when
   the backend traces them (forest_path), else from a pass of their own
   (:meth:`Backend.first_hits`); one ray through each pixel centre gives
   ``depth``, ``id`` and ``species`` (:meth:`Backend.layers`);
5. :meth:`Backend.post` finishes the beauty (``scalar_rgb``'s haze), and Open Image Denoise cleans it,
   guided by the albedo and normal (:func:`forest.imaging.denoise`), where ``[render] denoise`` says so
   (:func:`forest.imaging.denoise.denoise_rule`: ``--preview``, ``true``, or ``"auto"`` at spp ≤
   :data:`~forest.imaging.denoise.AUTO_MAX_SPP`);
6. the comp AOVs of ``[render] aovs`` (:func:`forest.render.path.aovs.frame_aovs`) are attached: N and
   albedo from the first hits, P and motion from the pixel-centre layers, the light groups from the
   backend's sums of the beauty's passes (forest_path only).
"""

from __future__ import annotations

import math
import time
import weakref
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from ..camera import camera_at, subframe_times
from ..imaging import denoise
from ..imaging.denoise import denoise_rule
from ..scene import Scene
from .coverage import SampleCoverage, frame_mattes, sample_ids
from .output import FrameImage
from .path.aovs import GroupSums, frame_aovs
from .path.frame import PassResult
from .path.integrator import NO_HIT

if TYPE_CHECKING:
    from ..camera import CameraState
    from ..config import Config

#: ``on_pass(image so far, passes done, passes in the frame)``; the image (H, W, 3) float32 is made only when
#: the callback calls it (a 1080p frame's mean costs ~0.1 s, which a progress bar alone need not pay every pass).
PassCallback = Callable[[Callable[[], np.ndarray], int, int], None]


def frame_seed(config: Config, frame: float) -> int:
    """The seed of sub-frame 0 of ``frame`` (sub-frame k adds 101·k)."""
    return int(config.render.seed) * 1_000_003 + int(round(frame * 1000)) * 997


class Backend(Protocol):
    """What a renderer does for the frame loop: pose its scene, trace samples, first hits and layers."""

    scene: Scene
    width: int
    height: int
    spp: int
    subframes: int
    preview: bool
    load_seconds: float
    render_seconds: float
    lod_counts: dict[str, int]
    max_instanced: int
    max_unique: int
    max_groups: int

    @property
    def leaf_model(self) -> str:
        """How the leaves are shaded (written to the EXR header)."""

    def restart(self) -> None:
        """Start the statistics of a new render that reuses this backend."""

    def stats(self) -> dict[str, object]:
        """The loaded scene's statistics for the EXR header."""

    def passes(self, spp: int) -> list[int]:
        """Samples per pixel of each pass of ``spp`` samples."""

    def pose(self, levels: np.ndarray, time_s: float) -> None:
        """Load the scene with these levels of detail and the wind at ``time_s`` (a no-op when already loaded)."""

    def samples(self, frame: float, spp: int, seed: int) -> Iterator[PassResult]:
        """The beauty's passes of ``spp`` samples per pixel at camera time ``frame`` in the loaded pose; each
        :class:`PassResult` holds per-pixel sums, and its first hits (``rows``, ``alpha``, ``albedo``,
        ``normal``) when the backend traces them with the beauty."""

    def first_hits(self, frame: float, levels: np.ndarray) -> Iterator[PassResult]:
        """Passes of first hits only (``rows``, ``alpha``, ``albedo``, ``normal``) at the frame's centre, for a
        backend whose beauty passes carry none."""

    def layers(self, frame: float, levels: np.ndarray) -> dict[str, np.ndarray]:
        """``depth``, ``id`` and ``species`` (H, W) from one ray through each pixel centre at the frame's centre."""

    def post(self, rgb: np.ndarray, alpha: np.ndarray, layers: dict[str, np.ndarray], frame: float) -> np.ndarray:
        """The beauty (H, W, 3) finished (e.g. haze applied after the fact); ``alpha`` (H, W) is the coverage."""

    def frame_lod_counts(self) -> dict[str, int]:
        """Trees per level of detail in the pose just rendered."""


class FirstHits:
    """Sums of the first hits of a frame's samples: coverage, per-sample ids, albedo and normal."""

    def __init__(self, scene: Scene, height: int, width: int):
        self.instances = scene.instances
        self.n_trees = len(scene.instances)
        self.height, self.width = height, width
        n = height * width
        self.alpha = np.zeros(n)
        self.albedo = np.zeros((n, 3))
        self.normal = np.zeros((n, 3))
        self.coverage = SampleCoverage(height, width)
        self.samples = 0
        self.counts: np.ndarray | None = None  # per-pixel samples, once an adaptive pass came

    @property
    def empty(self) -> bool:
        """No pass added yet."""
        return self.samples == 0 and self.counts is None

    def add(self, p: PassResult) -> None:
        """Add one pass's first hits (its ``rows`` must be set; an adaptive pass's untraced pixels ``NO_HIT``)."""
        assert p.rows is not None and p.albedo is not None and p.normal is not None
        self.coverage.add(sample_ids(p.rows, self.instances.id, n_trees=self.n_trees, no_hit=NO_HIT))
        self.alpha += p.alpha
        self.albedo += p.albedo
        self.normal += p.normal
        counts = p.counts
        if counts is None:
            self.samples += p.spp
            return
        self.coverage.total += counts - p.spp  # the pixels this pass did not trace took no samples
        self.counts = counts.astype(np.float64) if self.counts is None else self.counts + counts

    def image(self, a: np.ndarray, channels: int) -> np.ndarray:
        """A per-pixel sum as its mean image, (H, W) or (H, W, channels), float32."""
        shape = (self.height, self.width) if channels == 1 else (self.height, self.width, channels)
        if self.counts is None:
            return (a / max(self.samples, 1)).reshape(shape).astype(np.float32)
        n = np.maximum(self.counts + self.samples, 1.0)
        return (a / (n if channels == 1 else n[:, None])).reshape(shape).astype(np.float32)


class Beauty:
    """The running beauty of a frame: Σ L / Σ samples, or — with adaptive passes (per-pixel counts) — the mean
    over the sub-frames of each sub-frame's per-pixel mean (the module docstring, step 3)."""

    def __init__(self, pixels: int):
        self.rgb = np.zeros((pixels, 3))
        self.samples = 0
        self.counts: np.ndarray | None = None  # the sub-frame's per-pixel samples (adaptive)
        self.means = np.zeros((pixels, 3))  # Σ of the finished sub-frames' per-pixel means (adaptive)
        self.subframes = 0

    def add(self, p: PassResult) -> None:
        """Add one pass's sums."""
        self.rgb += p.rgb
        counts = p.counts
        if counts is None:
            self.samples += p.spp
        else:
            self.counts = counts.astype(np.float64) if self.counts is None else self.counts + counts

    def _sub_mean(self) -> np.ndarray:
        assert self.counts is not None
        return self.rgb / np.maximum(self.counts, 1.0)[:, None]

    def end_subframe(self) -> None:
        """Close an adaptive sub-frame (no-op otherwise): fold its mean in, start the next from zero."""
        if self.counts is None:
            return
        self.means += self._sub_mean()
        self.subframes += 1
        self.rgb[:] = 0.0
        self.counts = None

    def image(self) -> np.ndarray:
        """The mean so far, (H·W, 3) float64."""
        if self.subframes == 0 and self.counts is None:
            return self.rgb / self.samples
        if self.counts is None:
            return self.means / self.subframes
        return (self.means + self._sub_mean()) / (self.subframes + 1)


#: Pixels a tree's top may sway between two wind poses of one frame however still the camera is (step 2).
POSE_PIXELS = 1.0


def pose_count(scene: Scene, frame: float, times: list[float], width: int, height: int) -> int:
    """m, the wind poses the sub-frames at ``times`` (frames, in time order) of ``frame`` share in a
    ``width`` × ``height`` image (step 2)."""
    from ..imaging.camera_matrices import camera_matrices
    from ..wind import tree_matrices

    wind, cam = scene.config.wind, scene.config.camera
    k = len(times)
    inst = scene.instances
    if k <= 1 or wind.strength <= 0 or not len(inst):
        return 1
    if not scene.lod.heights:  # no heights to measure the sway by: every sub-frame its own pose
        return k
    w, h = int(width), int(height)
    tall = np.asarray(scene.lod.heights, np.float64)[np.asarray(inst.species, np.int64)]
    local = np.zeros((len(inst), 4))
    local[:, 1], local[:, 3] = tall, 1.0  # the top of each tree's highest level, in its own frame

    def tops(t: float) -> np.ndarray:
        return np.einsum("nij,nj->ni", tree_matrices(inst, t / cam.fps, wind), local)[:, :3]

    def pixels(state: CameraState, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m = camera_matrices(state.position, state.target, state.up, state.fov, w, h)
        z = (np.c_[points, np.ones(len(points))] @ m.world_to_camera.T)[:, 2]
        return m.project(points)[:, :2] * (w, h), z

    at = scene.camera_at(frame)
    mid = tops(frame)
    centre, depth = pixels(at, mid)
    seen = (depth > 0.0) & (centre[:, 0] > -0.1 * w) & (centre[:, 0] < 1.1 * w)
    seen &= (centre[:, 1] > -0.1 * h) & (centre[:, 1] < 1.1 * h)
    if not seen.any():
        return 1
    mid = mid[seen]
    sway = np.linalg.norm(pixels(at, tops(times[-1])[seen])[0] - pixels(at, tops(times[0])[seen])[0], axis=1)
    moved = pixels(scene.camera_at(times[-1]), mid)[0] - pixels(scene.camera_at(times[0]), mid)[0]
    step = np.linalg.norm(moved, axis=1) / (k - 1)
    need = np.ceil(sway / np.maximum(POSE_PIXELS, step)).max()
    return int(min(k, max(1, need)))


#: The last :func:`pose_times` answer: (a weak reference to its Scene, its arguments, the poses).  A renderer built
#: for a frame asks for that frame's poses (:func:`first_pose_time`) just before :func:`render_frame` does, and
#: :func:`pose_count` projects every tree twice (0.1 s for the fly-through's 130 000 trees).
_last_poses: tuple[Any, tuple[Any, ...], list[float]] | None = None


def pose_times(scene: Scene, frame: float, times: list[float], width: int, height: int) -> list[float]:
    """The wind pose (in frames) of each sub-frame at ``times`` (frames, in time order): the mean time of its run
    of the :func:`pose_count` runs (step 2); the sub-frames' own times when each has its own pose."""
    global _last_poses
    key = (float(frame), tuple(float(t) for t in times), int(width), int(height), POSE_PIXELS)
    last = _last_poses
    if last is not None and last[0]() is scene and last[1] == key:
        return list(last[2])
    k = len(times)
    m = pose_count(scene, frame, times, width, height)
    if m >= k:
        poses = list(times)
    else:
        runs = [j * m // k for j in range(k)]
        means = [float(np.mean([t for t, r in zip(times, runs) if r == g])) for g in range(m)]
        poses = [means[r] for r in runs]
    _last_poses = (weakref.ref(scene), key, list(poses))
    return poses


def subframe_order(times: list[float], frame: float, poses: list[float] | None = None) -> list[int]:
    """The order sub-frames are rendered in (step 2): their poses' runs farthest from the frame's centre first,
    the centre's last; within a run, farthest first."""
    poses = times if poses is None else poses
    return sorted(range(len(times)), key=lambda k: (-abs(poses[k] - frame), -abs(times[k] - frame), k))


def first_pose_time(scene: Scene, frame: float, subframes: int, width: int, height: int) -> float:
    """Seconds of the first wind pose :func:`render_frame` loads for ``frame``: a backend that loads that pose
    when it is built has its first :meth:`Backend.pose` already done (one scene build fewer with wind)."""
    cam = scene.config.camera
    times = subframe_times(frame, cam.shutter, subframes)
    poses = pose_times(scene, frame, times, width, height)
    return poses[subframe_order(times, frame, poses)[0]] / cam.fps


def render_frame(
    backend: Backend, frame: float, on_pass: PassCallback | None = None, groups: GroupSums | None = None
) -> FrameImage:
    """Render one frame with ``backend`` by the recipe of the module docstring; ``groups``: the light-group sums
    the backend's passes fill (None: no light groups)."""
    scene = backend.scene
    config, cam = scene.config, scene.config.camera
    w, h = backend.width, backend.height
    levels = scene.levels(frame) if len(scene.instances) else np.zeros(0, np.int64)
    times = subframe_times(frame, cam.shutter, backend.subframes)
    poses = pose_times(scene, frame, times, w, h)
    order = subframe_order(times, frame, poses)
    spp_sub = max(1, math.ceil(backend.spp / len(times)))
    total = len(times) * len(backend.passes(spp_sub))
    beauty = Beauty(h * w)
    done = 0
    hits = FirstHits(scene, h, w)
    seed = frame_seed(config, frame)
    for k in order:
        backend.pose(levels, poses[k] / cam.fps)
        t0 = time.perf_counter()
        for p in backend.samples(times[k], spp_sub, seed + 101 * k):
            beauty.add(p)
            done += 1
            if p.rows is not None:
                hits.add(p)
            if on_pass is not None:
                on_pass(lambda: beauty.image().reshape(h, w, 3).astype(np.float32), done, total)
        beauty.end_subframe()
        backend.render_seconds += time.perf_counter() - t0
    t0 = time.perf_counter()
    if hits.empty:
        for p in backend.first_hits(frame, levels):
            hits.add(p)
    layers = backend.layers(frame, levels)
    mattes = frame_mattes(hits.coverage, scene.instances, [str(n) for n in scene.instances.species_names])
    backend.render_seconds += time.perf_counter() - t0
    for name, c in backend.frame_lod_counts().items():
        backend.lod_counts[name] = backend.lod_counts.get(name, 0) + c
    alpha = hits.image(hits.alpha, 1)
    albedo, normal = hits.image(hits.albedo, 3), hits.image(hits.normal, 3)
    rgb = backend.post(beauty.image().reshape(h, w, 3).astype(np.float32), alpha, layers, frame)
    denoised = False
    if denoise_rule(config.render.denoise, backend.spp, preview=backend.preview)[0]:
        d = denoise(rgb, albedo, normal)
        if d is not None:
            rgb, denoised = d, True
    return FrameImage(
        rgb=rgb,
        alpha=alpha,
        depth=layers["depth"],
        id=layers["id"],
        species=layers["species"],
        camera=camera_at(cam, frame),
        levels=levels,
        mattes=mattes,
        albedo=albedo,
        normal=normal,
        denoised=denoised,
        aovs=frame_aovs(
            config.render.aovs,
            config=config,
            instances=scene.instances,
            frame=frame,
            normal=normal,
            albedo=albedo,
            layers=layers,
            groups=groups,
        ),
    )
