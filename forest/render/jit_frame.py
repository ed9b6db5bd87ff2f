"""Rendering the frames of a Scene with forest_path, forest's path tracer (``llvm_ad_rgb``, ``cuda_ad_rgb``).

:class:`PathFrameRenderer` is the frame loop's backend (:mod:`forest.render.loop`,
the recipe of a frame, shared with ``scalar_rgb``) over a
:class:`~forest.render.path.PathScene`: :meth:`PathScene.pose` reloads the
traversal scene only when the pose changes (wind, or a new LOD plan); each
sub-frame traces its samples in passes of at most
``forest.render.path.frame.MAX_LANES`` paths, and every sample also reports
what its camera ray met first (tree, ground or nothing), the albedo and the
shading normal there — the coverage, the Cryptomattes and the denoiser's
guides come with the beauty.  Aerial perspective is part of the path
(:mod:`forest.render.path.haze`), not a post-process.  The comp AOVs of
``[render] aovs`` (:mod:`forest.render.path.aovs`) come from the same traversal:
the light groups from the beauty's own samples (``lightgroups`` switches their
split on in the kernel), N and albedo from its first hits, P and the motion
vectors from the pixel-centre layers pass.

With ``[render] noise_threshold`` > 0 the sub-frame's samples are adaptive
(:mod:`forest.render.adaptive`): every pixel takes ``min_spp`` samples, then
rounds of ``min_spp`` more go only to the pixels whose relative error is still
above the threshold (or next to one that is); each pass's rays are built for
those pixels alone, so a stopped pixel costs nothing.  The passes carry
per-pixel sample counts, and the image is each pixel's mean over its samples.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from ..runtime import mitsuba
from ..scene import Scene
from ..wind import tree_matrices
from .adaptive import LUMA, Convergence, chunks, default_min_spp, rounds_passes, schedule
from .frame import FrameSize
from .loop import PassCallback, first_pose_time, frame_seed, render_frame
from .output import FrameImage
from .path import PathScene
from .path.aovs import GroupSums
from .path.frame import PassResult, pass_seed, split_passes
from .path.from_scene import path_camera, path_inputs


def _no_progress(_fraction: float, _step: str) -> None:
    """A progress callback that reports nothing."""


class PixelGroupSums(GroupSums):
    """Light groups of adaptive passes: each pixel's mean over its own samples, averaged over the sub-frames
    (as the beauty is, :func:`forest.render.loop.render_frame`)."""

    def __init__(self, pixels: int):
        super().__init__(pixels)
        self.means = {g: np.zeros((self.pixels, 3)) for g in self.sums}
        self.counts = np.zeros(self.pixels)
        self.subframes = 0

    def add(self, p: PassResult) -> None:
        """Add one adaptive pass's group sums and its per-pixel counts."""
        for g, v in (p.groups or {}).items():
            self.sums[g] += v
        self.counts += p.spp if p.counts is None else p.counts

    def end_subframe(self) -> None:
        """Fold the sub-frame's per-pixel means into the frame's and start the next sub-frame."""
        n = np.maximum(self.counts, 1.0)[:, None]
        for g, v in self.sums.items():
            self.means[g] += v / n
            v[:] = 0.0
        self.counts[:] = 0.0
        self.subframes += 1

    def images(self, height: int, width: int) -> dict[str, np.ndarray]:
        """``lightgroup.<g>`` → (H, W, 3) float32: the mean over the sub-frames of each pixel's mean."""
        k = max(self.subframes, 1)
        return {f"lightgroup.{g}": (v / k).reshape(height, width, 3).astype(np.float32) for g, v in self.means.items()}


class PathFrameRenderer:
    """Renders the frames of one :class:`~forest.scene.Scene` with forest_path (see the module docstring).

    State kept across frames (and across renders, through ``render_scene(reuse=…)``):
    the part buffers, materials, textures and lights of the :class:`PathScene`, and the
    traversal scene of the last pose.
    """

    leaf_model = "forest_path (R = (1-t)a reflected, T = ta transmitted)"

    def __init__(
        self,
        scene: Scene,
        variant: str,
        size: FrameSize,
        *,
        preview: bool = False,
        progress: Callable[[float, str], None] | None = None,
        frame: float = 1.0,
    ):
        self.scene = scene
        self.config = config = scene.config
        self.instances = scene.instances
        self.variant = variant
        self.preview = preview
        self.width, self.height, self.spp, self.subframes = size.width, size.height, size.spp, size.subframes
        self.species_names = [str(n) for n in self.instances.species_names]
        t0 = time.perf_counter()
        report = progress or _no_progress
        report(0.0, f"loading Mitsuba ({variant})")
        mitsuba(variant)
        report(0.15, f"levels of detail and wind of {len(self.instances):,} trees")
        # The levels and wind of the first pose the frame loop loads for ``frame`` (the first frame to render), so
        # that pose is this one and the first frame costs no second build.
        t_first = first_pose_time(scene, frame, self.subframes, self.width, self.height)
        inputs = path_inputs(scene, frame=frame, width=self.width, height=self.height, spp=self.spp, time_s=t_first)
        report(0.25, f"Mitsuba scene of {len(self.instances):,} trees, {len(scene.species)} species")
        self.path = PathScene(inputs, variant, progress=lambda f, m: report(0.25 + 0.75 * f, m))
        report(1.0, "scene built")
        self._frame = frame  # the frame being rendered, whose camera decides the solid cards (Scene.solid_cards)
        self._solid = inputs.solid  # the trees drawn with solid cards in the loaded pose
        self._pose_key = self._key(inputs.levels, t_first)
        self.aovs = tuple(config.render.aovs)
        self._groups: GroupSums | None = None  # the light groups of the frame being rendered
        rc = config.render
        self.noise_threshold = float(rc.noise_threshold)
        self.min_spp = default_min_spp(self.spp) if rc.min_spp is None else min(int(rc.min_spp), self.spp)
        self.restart()
        self.load_seconds = time.perf_counter() - t0

    # -- bookkeeping ---------------------------------------------------------------------
    def restart(self) -> None:
        """Start the statistics of a new render that reuses this renderer (and its loaded pose)."""
        self.load_seconds = 0.0
        self.render_seconds = 0.0
        self.lod_counts: dict[str, int] = {}
        st = self.path.stats
        self.max_instanced = st.instanced_triangles + st.flattened_triangles
        self.max_unique = int(self.path.geometry.parts.n_faces)
        self.max_groups = st.shapegroups
        self.samples_traced = 0.0  # mean samples per pixel traced in the last frame

    def stats(self) -> dict[str, object]:
        """The loaded pose's statistics for the EXR header."""
        st = self.path.stats
        return {
            "trees": st.trees,
            "instanced_triangles": st.instanced_triangles + st.flattened_triangles,
            "unique_triangles": int(self.path.geometry.parts.n_faces),
            "shapegroups": st.shapegroups,
            "instances": st.instances,
            "merged_far_trees": st.flattened_trees,
            "lod": ", ".join(f"{k}={v}" for k, v in st.lod_counts.items()),
            "samples_traced": round(float(self.samples_traced), 3),
        }

    def passes(self, spp: int) -> list[int]:
        """Samples per pixel of each pass of ``spp`` samples (adaptive: while every pixel is still going)."""
        if self.noise_threshold > 0.0:
            return rounds_passes(self.width, self.height, spp, min(self.min_spp, spp), self.path.max_lanes)
        return split_passes(self.width, self.height, spp, self.path.max_lanes)

    def _key(self, levels: np.ndarray, time_s: float) -> tuple[bytes, bytes, float | None]:
        wind = self.config.wind
        solid = b"" if self._solid is None else np.packbits(self._solid).tobytes()
        return (np.asarray(levels).tobytes(), solid, round(time_s, 9) if wind.strength > 0 else None)

    def _pose(self, levels: np.ndarray, time_s: float) -> None:
        self._solid = self.scene.solid_cards(self._frame, levels) if len(self.instances) else None
        key = self._key(levels, time_s)
        if key == self._pose_key:
            return
        t0 = time.perf_counter()
        self.path.pose(levels, tree_matrices(self.instances, time_s, self.config.wind), solid=self._solid)
        self._pose_key = key
        self.load_seconds += time.perf_counter() - t0
        st = self.path.stats
        self.max_instanced = max(self.max_instanced, st.instanced_triangles + st.flattened_triangles)
        self.max_unique = max(self.max_unique, int(self.path.geometry.parts.n_faces))
        self.max_groups = max(self.max_groups, st.shapegroups)

    # -- the frame loop's backend (forest.render.loop) -----------------------------------
    def pose(self, levels: np.ndarray, time_s: float) -> None:
        """Load the pose (levels of detail, wind at ``time_s``); see :meth:`PathScene.pose`."""
        self._pose(levels, time_s)

    def samples(self, frame: float, spp: int, seed: int) -> Iterator[PassResult]:
        """The beauty's passes at camera time ``frame``, each with its samples' first hits."""
        camera = path_camera(self.config, frame, self.width, self.height)
        groups = self._groups
        if self.noise_threshold > 0.0:
            yield from self._adaptive(camera, spp, seed)
            return
        for p in self.path.passes(camera, spp=spp, seed=seed, aux=True, groups=groups is not None):
            if groups is not None:
                groups.add(p)
            self.samples_traced += p.spp
            yield p

    def _adaptive(self, camera: Any, spp: int, seed: int) -> Iterator[PassResult]:
        """Adaptive passes of one sub-frame (the module docstring): rounds of :func:`~.adaptive.schedule`, each
        cut into passes of at most ``max_lanes`` paths over the pixels still going, pass k seeded
        :func:`~.path.frame.pass_seed` (seed, k); a convergence test after every round."""
        import drjit as dr

        w, h = self.width, self.height
        conv = Convergence(h, w, self.noise_threshold)
        groups = self._groups
        kernel = self.path.kernel()
        pixels = np.arange(w * h)
        k = 0
        with dr.suspend_grad():
            for r, s in enumerate(schedule(spp, min(self.min_spp, spp))):
                if r > 0:
                    pixels = conv.update()
                    if len(pixels) == 0:
                        break
                for part in chunks(pixels, s, self.path.max_lanes):
                    p = self.path.sample_pass(
                        kernel,
                        camera,
                        s,
                        pass_seed(seed, k),
                        pixels=part,
                        aux=True,
                        groups=groups is not None,
                        luma=LUMA,
                    )
                    k += 1
                    conv.add(p)
                    if groups is not None:
                        groups.add(p)
                    assert p.counts is not None
                    self.samples_traced += float(p.counts.sum()) / (w * h)
                    yield p
        if isinstance(groups, PixelGroupSums):
            groups.end_subframe()

    def first_hits(self, frame: float, levels: np.ndarray) -> Iterator[PassResult]:
        """First hits at the frame's centre (the loop needs none: :meth:`samples` carries them)."""
        self._frame = frame
        self._pose(levels, frame / self.config.camera.fps)
        camera = path_camera(self.config, frame, self.width, self.height)
        yield from self.path.first_hits(camera, spp=self.spp, seed=frame_seed(self.config, frame))

    def layers(self, frame: float, levels: np.ndarray) -> dict[str, np.ndarray]:
        """Depth, id and species through the pixel centres at the frame's centre pose."""
        self._frame = frame
        self._pose(levels, frame / self.config.camera.fps)
        return self.path.layers(path_camera(self.config, frame, self.width, self.height))

    def post(
        self,
        rgb: np.ndarray,
        alpha: np.ndarray,  # noqa: ARG002 (the Backend protocol's signature)
        layers: dict[str, np.ndarray],  # noqa: ARG002
        frame: float,  # noqa: ARG002
    ) -> np.ndarray:
        """The beauty as traced: haze is part of forest_path's paths (the Backend protocol's other arguments are
        for renderers that finish their beauty after the fact)."""
        return rgb

    def frame_lod_counts(self) -> dict[str, int]:
        """Trees per level of detail in the loaded pose."""
        return dict(self.path.stats.lod_counts)

    def frame(self, frame: float, on_pass: PassCallback | None = None) -> FrameImage:
        """Render one frame (:func:`forest.render.loop.render_frame`); ``on_pass`` is called after every pass (its
        first argument gives the running mean); its comp AOVs (``[render] aovs``, light groups included) come attached to the image."""
        sums = PixelGroupSums if self.noise_threshold > 0.0 else GroupSums
        self._groups = sums(self.width * self.height) if "lightgroups" in self.aovs else None
        self.samples_traced = 0.0
        self._frame = frame
        try:
            return render_frame(self, frame, on_pass, self._groups)
        finally:
            self._groups = None
