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
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import numpy as np

from ..runtime import mitsuba
from ..scene import Scene
from ..wind import tree_matrices
from .frame import FrameSize
from .loop import PassCallback, frame_seed, render_frame
from .output import FrameImage
from .path import PathScene
from .path.aovs import GroupSums, frame_aovs
from .path.frame import PassResult, split_passes
from .path.from_scene import path_camera, path_inputs


def _no_progress(_fraction: float, _step: str) -> None:
    """A progress callback that reports nothing."""


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
        inputs = path_inputs(scene, frame=1.0, width=self.width, height=self.height, spp=self.spp)
        report(0.25, f"Mitsuba scene of {len(self.instances):,} trees, {len(scene.species)} species")
        self.path = PathScene(inputs, variant)
        report(1.0, "scene built")
        self._pose_key = self._key(inputs.levels, 1.0 / config.camera.fps)
        self.aovs = tuple(config.render.aovs)
        self._groups: GroupSums | None = None  # the light groups of the frame being rendered
        self._layers: dict[str, np.ndarray] = {}
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
        return split_passes(self.width, self.height, spp, self.path.max_lanes)

    def _key(self, levels: np.ndarray, time_s: float) -> tuple[bytes, float | None]:
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

    # -- the frame loop's backend (forest.render.loop) -----------------------------------
    def pose(self, levels: np.ndarray, time_s: float) -> None:
        """Load the pose (levels of detail, wind at ``time_s``); see :meth:`PathScene.pose`."""
        self._pose(levels, time_s)

    def samples(self, frame: float, spp: int, seed: int) -> Iterator[PassResult]:
        """The beauty's passes at camera time ``frame``, each with its samples' first hits."""
        camera = path_camera(self.config, frame, self.width, self.height)
        groups = self._groups
        for p in self.path.passes(camera, spp=spp, seed=seed, aux=True, groups=groups is not None):
            if groups is not None:
                groups.add(p)
            yield p

    def first_hits(self, frame: float, levels: np.ndarray) -> Iterator[PassResult]:
        """First hits at the frame's centre (the loop needs none: :meth:`samples` carries them)."""
        self._pose(levels, frame / self.config.camera.fps)
        camera = path_camera(self.config, frame, self.width, self.height)
        yield from self.path.first_hits(camera, spp=self.spp, seed=frame_seed(self.config, frame))

    def layers(self, frame: float, levels: np.ndarray) -> dict[str, np.ndarray]:
        """Depth, id and species through the pixel centres at the frame's centre pose."""
        self._pose(levels, frame / self.config.camera.fps)
        self._layers = self.path.layers(path_camera(self.config, frame, self.width, self.height))
        return self._layers

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
        """Render one frame (:func:`forest.render.loop.render_frame`); ``on_pass`` sees the running mean after
        every pass; its comp AOVs (``[render] aovs``) are attached to the image."""
        self._groups = GroupSums(self.width * self.height) if "lightgroups" in self.aovs else None
        image = render_frame(self, frame, on_pass)
        image.aovs = frame_aovs(
            self.aovs,
            config=self.config,
            instances=self.instances,
            frame=frame,
            normal=image.normal,
            albedo=image.albedo,
            layers=self._layers,
            groups=self._groups,
        )
        self._groups = None
        return image
