"""Rendering the frames of a Scene with forest_path, forest's path tracer (``llvm_ad_rgb``, ``cuda_ad_rgb``).

The same frame recipe as :mod:`forest.render.frame` (``scalar_rgb``), through
:class:`~forest.render.path.PathScene`:

1. the camera at frame f is interpolated along its keys; every tree gets its
   level of detail from its distance to that camera (the Scene's plan);
2. with ``shutter`` s > 0 the frame averages K = ``[render] subframes``
   sub-frames at f + s·((k + ½)/K − ½), each with its own camera and wind pose
   (:meth:`PathScene.pose` reloads the traversal scene only when the pose
   changes: wind, or a new LOD plan).  The sub-frame nearest the frame's
   centre is rendered last, so the layers pass (step 4) finds its pose loaded;
3. each sub-frame traces ⌈spp / K⌉ samples per pixel in passes of at most
   ``forest.render.path.frame.MAX_LANES`` paths.  Every sample also reports
   what its camera ray met first (tree, ground or nothing), the albedo and the
   shading normal there: the coverage (alpha), the per-tree and per-species
   Cryptomattes (:mod:`forest.render.coverage`) and the denoiser's guides;
4. one ray through each pixel centre gives ``depth``, ``id`` and ``species``;
5. ``--preview`` denoises with Open Image Denoise guided by the albedo and
   normal (:func:`forest.imaging.denoise`).

Aerial perspective is part of the path (:mod:`forest.render.path.haze`), not a
post-process.  Seeds: sub-frame k of frame f starts from
``seed · 1 000 003 + round(1000 f) · 997 + 101 k``, the same numbers the
scalar renderer uses, so a frame's image depends only on the config and the
frame number.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from ..camera import camera_at, subframe_times
from ..imaging import denoise
from ..scene import Scene
from ..wind import tree_matrices
from .coverage import SampleCoverage, frame_mattes, sample_ids
from .frame import FrameSize
from .output import FrameImage
from .path import PathScene
from .path.frame import split_passes
from .path.from_scene import path_camera, path_inputs
from .path.integrator import NO_HIT

#: ``on_pass(image so far, passes done, passes in the frame)``.
PassCallback = Callable[[np.ndarray, int, int], None]


def frame_seed(config, frame: float) -> int:
    """The seed of sub-frame 0 of ``frame`` (sub-frame k adds 101·k)."""
    return int(config.render.seed) * 1_000_003 + int(round(frame * 1000)) * 997


class PathFrameRenderer:
    """Renders the frames of one :class:`~forest.scene.Scene` with forest_path (see the module docstring).

    State kept across frames (and across renders, through ``render_scene(reuse=…)``):
    the part buffers, materials, textures and lights of the :class:`PathScene`, and the
    traversal scene of the last pose.
    """

    leaf_model = "forest_path (R = (1-t)a reflected, T = ta transmitted)"

    def __init__(self, scene: Scene, variant: str, size: FrameSize, *, preview: bool = False):
        self.scene = scene
        self.config = config = scene.config
        self.instances = scene.instances
        self.variant = variant
        self.preview = preview
        self.width, self.height, self.spp, self.subframes = size.width, size.height, size.spp, size.subframes
        self.species_names = [str(n) for n in self.instances.species_names]
        t0 = time.perf_counter()
        inputs = path_inputs(scene, frame=1.0, width=self.width, height=self.height, spp=self.spp)
        self.path = PathScene(inputs, variant)
        self._pose_key = self._key(inputs.levels, 1.0 / config.camera.fps)
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
        }

    def passes(self, spp: int) -> list[int]:
        """Samples per pixel of each pass of ``spp`` samples."""
        return split_passes(self.width, self.height, spp)

    def _key(self, levels: np.ndarray, time_s: float) -> tuple:
        wind = self.config.wind
        return (np.asarray(levels).tobytes(), round(time_s, 9) if wind.strength > 0 else None)

    def _pose(self, levels: np.ndarray, time_s: float) -> None:
        key = self._key(levels, time_s)
        if key == self._pose_key:
            return
        t0 = time.perf_counter()
        self.path.pose(levels, tree_matrices(self.instances, time_s, self.config.wind))
        self._pose_key = key
        self.load_seconds += time.perf_counter() - t0
        st = self.path.stats
        self.max_instanced = max(self.max_instanced, st.instanced_triangles + st.flattened_triangles)
        self.max_unique = max(self.max_unique, int(self.path.geometry.parts.n_faces))
        self.max_groups = max(self.max_groups, st.shapegroups)

    # -- one frame -------------------------------------------------------------------------
    def frame(self, frame: float, on_pass: PassCallback | None = None) -> FrameImage:
        """Render one frame (see the module docstring); ``on_pass`` sees the running mean after every pass."""
        config, cam = self.config, self.config.camera
        w, h = self.width, self.height
        levels = self.scene.levels(frame) if len(self.instances) else np.zeros(0, np.int64)
        times = subframe_times(frame, cam.shutter, self.subframes)
        order = sorted(range(len(times)), key=lambda k: (-abs(times[k] - frame), k))  # the centre last
        spp_sub = max(1, math.ceil(self.spp / len(times)))
        total_passes = len(times) * len(self.passes(spp_sub))
        rgb = np.zeros((h * w, 3))
        alpha = np.zeros(h * w)
        albedo = np.zeros((h * w, 3))
        normal = np.zeros((h * w, 3))
        samples = 0
        done = 0
        coverage = SampleCoverage(h, w)
        n_trees = len(self.instances)
        seed = frame_seed(config, frame)
        for k in order:
            t = times[k]
            self._pose(levels, t / cam.fps)
            camera = path_camera(config, t, w, h)
            t0 = time.perf_counter()
            for p in self.path.passes(camera, spp=spp_sub, seed=seed + 101 * k, aux=True):
                assert p.albedo is not None and p.normal is not None and p.rows is not None  # aux=True
                rgb += p.rgb
                alpha += p.alpha
                albedo += p.albedo
                normal += p.normal
                samples += p.spp
                done += 1
                coverage.add(sample_ids(p.rows, self.instances.id, n_trees=n_trees, no_hit=NO_HIT))
                if on_pass is not None:
                    on_pass((rgb / samples).reshape(h, w, 3).astype(np.float32), done, total_passes)
            self.render_seconds += time.perf_counter() - t0
        self._pose(levels, frame / cam.fps)
        t0 = time.perf_counter()
        layers = self.path.layers(path_camera(config, frame, w, h))
        mattes = frame_mattes(coverage, self.instances, self.species_names)
        self.render_seconds += time.perf_counter() - t0
        for name, c in self.path.stats.lod_counts.items():
            self.lod_counts[name] = self.lod_counts.get(name, 0) + c
        beauty = (rgb / samples).reshape(h, w, 3).astype(np.float32)
        guide_a = (albedo / samples).reshape(h, w, 3).astype(np.float32)
        guide_n = (normal / samples).reshape(h, w, 3).astype(np.float32)
        denoised = False
        if self.preview:
            d = denoise(beauty, guide_a, guide_n)
            if d is not None:
                beauty, denoised = d, True
        return FrameImage(
            rgb=beauty,
            alpha=(alpha / samples).reshape(h, w).astype(np.float32),
            depth=layers["depth"],
            id=layers["id"],
            species=layers["species"],
            camera=camera_at(cam, frame),
            levels=levels,
            mattes=mattes,
            albedo=guide_a,
            normal=guide_n,
            denoised=denoised,
        )
