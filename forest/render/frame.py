"""Rendering the frames of a Scene in ``scalar_rgb`` with Mitsuba's own integrators (``path``/``volpath``).

:class:`FrameRenderer` is the frame loop's backend (:mod:`forest.render.loop`,
the recipe of a frame, shared with forest_path).  What it does itself:

* a pose is a Mitsuba scene of shapegroups and instances
  (:mod:`forest.render.instancing`), rebuilt only when the levels of detail or
  the wind pose change — Mitsuba 3 has no animated transforms, so motion blur
  is the loop's box-filtered average of sub-frames;
* each sub-frame renders in passes of equal size (:data:`SCALAR_PASS_SPP` at
  most) with consecutive seeds, which also drives progress and the live image;
* coverage, ids and the denoiser's guides come from forest_path's traversal of
  the same forest (:meth:`forest.render.path.PathScene.first_hits` and
  :meth:`~forest.render.path.PathScene.layers`, in ``llvm_ad_rgb``): up to
  :data:`COVERAGE_SPP` jittered camera samples per pixel give the alpha, the
  per-sample ids of the Cryptomattes and the first-hit albedo and normal; one
  ray through each pixel centre gives ``depth``, ``id`` and ``species``.  (It
  replaces a per-pixel Python loop over ``Scene.ray_intersect`` that took
  36–51 s a frame at 1280×720.)
* aerial perspective is a post-process here (:func:`forest.render.post.apply_haze`):
  the height-falloff model of :mod:`forest.render.path.haze` applied along
  each pixel's camera ray, split between the pixel's geometry and its sky by
  the coverage — forest_path applies the same model along every path segment.
* the comp AOVs of ``[render] aovs`` (:mod:`forest.render.path.aovs`): N and albedo
  from the coverage pass's first hits, P and the motion vectors from the layers
  pass.  Light groups need forest_path's estimator: asked for here, a one-line
  warning names the variant and no ``lightgroup.*`` layers are written.

The look: leaves with τ > 0 are ``principledthin`` (diffuse transmission),
shadow rays see through leaf-card alpha (``volpath``, ``[render]
alpha_shadows``, on by default), the sun is a disc (an area light far away),
``sunsky`` is rotated to Y-up, the ground runs on to the horizon.  What
differs from forest_path: the leaves' texture detail under the colour map and
the ground's detail texture are averaged (no Python plugin per sample), haze
acts on camera rays only, and the sunsky's own sun lights the scene.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ForestError
from ..runtime import load_scene_dict, mitsuba
from ..scene import Scene
from ..skirt import hills, skirt_radius
from ..wind import tree_matrices
from .instancing import ForestBuilder, ForestGraph
from .loop import PassCallback, frame_seed, render_frame
from .materials import MaterialBuilder
from .output import FrameImage
from .path import PathScene
from .path.frame import PassResult
from .path.from_scene import path_camera, path_inputs
from .post import apply_haze
from .scene import emitter_dicts, ground_dicts, sensor_dict

#: Samples per pass in scalar_rgb (more passes = finer progress, same image statistics).
SCALAR_PASS_SPP = 8
#: Russian roulette from this path depth on (unbiased; dark foliage paths end early).
RR_DEPTH = 2
#: Camera samples per pixel (at most) of the coverage pass: alpha, Cryptomattes, denoiser guides.
COVERAGE_SPP = 16


@dataclass(frozen=True)
class FrameSize:
    """Image size, samples per pixel and motion-blur sub-frames of a render."""

    width: int
    height: int
    spp: int
    subframes: int = 1


class FrameRenderer:
    """Renders the frames of one :class:`~forest.scene.Scene` in ``scalar_rgb`` (see the module docstring).

    State kept across frames: the materials, the shapegroups, the last Mitsuba
    scene (rebuilt only when the LOD assignment or the wind pose changes) and
    the forest_path scene of the coverage and layers passes.
    """

    def __init__(self, scene: Scene, variant: str, size: FrameSize, *, preview: bool = False):
        self.scene = scene
        self.config = config = scene.config
        self.instances = scene.instances
        self.variant = variant
        self.mi = mitsuba(variant)
        rc = config.render
        self.preview = preview
        self.width, self.height, self.spp, self.subframes = size.width, size.height, size.spp, size.subframes
        self.species_names = [str(n) for n in self.instances.species_names]
        self.terrain = scene.terrain
        self.colour_grid = None if scene.colour is None else scene.colour.rgb
        self.materials = MaterialBuilder(variant, self.colour_grid, self.terrain.extent, self.terrain.height_range)
        self.forest = ForestBuilder(scene, self.materials)
        skirt = skirt_radius(self.terrain.extent, float(config.camera.far)) if rc.horizon_ground else 0.0
        self.terrain_obj, self.water_obj = ground_dicts(
            scene.terrain_albedo,
            self.terrain,
            variant,
            skirt=skirt,
            hills=hills(config),
            tint=scene.ground_tint,
            ripple=float(config.model.ground.water_ripple),
        )
        self.emitters = emitter_dicts(config, variant, disc_sun=True)
        # Mitsuba 3.9.1's ``path`` tests shadow rays against whole leaf cards (alpha ignored);
        # ``volpath`` attenuates them by each mask's opacity: exact, but 3–6× slower on foliage.
        self.integrator = {
            "type": "volpath" if rc.alpha_shadows else "path",
            "max_depth": int(rc.max_depth),
            "rr_depth": RR_DEPTH,
        }
        self._scene_key: tuple[bytes, float | None] | None = None
        self._scene: Any = None
        self._path: PathScene | None = None  # forest_path's scene of the coverage and layers passes, on first use
        self._path_key: tuple[bytes, float | None] | None = None
        self.graph: ForestGraph | None = None
        self.load_seconds = 0.0
        self.render_seconds = 0.0
        self.lod_counts: dict[str, int] = {}
        self.max_instanced = 0
        self.max_unique = 0
        self.max_groups = 0
        self.aovs = tuple(rc.aovs)
        self._layers: dict[str, np.ndarray] = {}
        if "lightgroups" in self.aovs:
            warnings.warn(
                f"render.aovs: light groups need forest_path (llvm_ad_rgb or cuda_ad_rgb); {variant} writes none",
                stacklevel=2,
            )

    @property
    def leaf_model(self) -> str:
        """How the leaves are shaded (written to the EXR header)."""
        return self.materials.leaf_model

    def restart(self) -> None:
        """Start the statistics of a new render that reuses this renderer (and its built scene)."""
        self.load_seconds = self.render_seconds = 0.0
        self.lod_counts = {}
        g = self.graph
        self.max_instanced, self.max_unique, self.max_groups = (
            (g.instanced_triangles, g.unique_triangles, g.shapegroups) if g is not None else (0, 0, 0)
        )

    def stats(self) -> dict[str, object]:
        """The current Mitsuba scene's statistics for the EXR header."""
        g = self.graph
        if g is None:
            return {}
        return {
            "trees": g.trees,
            "instanced_triangles": g.instanced_triangles,
            "unique_triangles": g.unique_triangles,
            "shapegroups": g.shapegroups,
            "instances": g.trees,
            "lod": ", ".join(f"{k}={v}" for k, v in g.lod_counts.items()),
        }

    # -- scene ---------------------------------------------------------------------
    def scene_at(self, levels: np.ndarray, time_s: float) -> Any:
        """The scene for an LOD assignment and a wind time (rebuilt only when either changes)."""
        mitsuba(self.variant)  # the coverage pass runs in llvm_ad_rgb: make scalar_rgb current again
        wind = self.config.wind
        key = (levels.tobytes(), round(time_s, 9) if wind.strength > 0 else None)
        if key == self._scene_key:
            return self._scene
        t0 = time.perf_counter()
        self._scene = None
        mats = tree_matrices(self.instances, time_s, wind)
        graph = self.forest.graph(levels, mats)
        scene = {"type": "scene", "integrator": self.integrator, "terrain": self.terrain_obj, **self.emitters}
        if self.water_obj is not None:
            scene["water"] = self.water_obj
        scene.update(graph.entries or {})
        try:
            self._scene = load_scene_dict(self.mi, scene)
        except Exception as e:
            raise ForestError(f"{self.config.path}: cannot build the Mitsuba scene: {str(e).splitlines()[0]}") from None
        del scene
        graph.entries = None  # the dicts are no longer needed: free them before rendering
        self.graph = graph
        self._scene_key = key
        self.max_instanced = max(self.max_instanced, graph.instanced_triangles)
        self.max_unique = max(self.max_unique, graph.unique_triangles)
        self.max_groups = max(self.max_groups, graph.shapegroups)
        self.load_seconds += time.perf_counter() - t0
        return self._scene

    def sensor(self, frame: float, spp: int, *, rfilter: str = "box") -> Any:
        """The Mitsuba sensor of the camera at (fractional) ``frame``, ``spp`` samples per pixel."""
        mitsuba(self.variant)
        return self.mi.load_dict(
            sensor_dict(self.config, frame, self.width, self.height, spp, self.variant, rfilter=rfilter)
        )

    def passes(self, spp: int) -> list[int]:
        """Samples per pixel of each pass of ``spp`` samples: as equal as possible, :data:`SCALAR_PASS_SPP` at most."""
        n = max(1, math.ceil(spp / SCALAR_PASS_SPP))
        base, extra = divmod(spp, n)
        return [base + (1 if i < extra else 0) for i in range(n)]

    def path_scene(self, levels: np.ndarray, time_s: float) -> PathScene:
        """forest_path's scene of the same forest in the same pose (``llvm_ad_rgb``), for coverage and layers."""
        wind = self.config.wind
        key = (levels.tobytes(), round(time_s, 9) if wind.strength > 0 else None)
        t0 = time.perf_counter()
        if self._path is None:
            inputs = path_inputs(self.scene, width=self.width, height=self.height, spp=1)
            inputs.haze = None  # applied here after the beauty
            inputs.solid = None  # the mattes of Mitsuba's beauty, whose cards keep their cut-outs
            self._path = PathScene(inputs, "llvm_ad_rgb")
            self._path_key = (
                inputs.levels.tobytes(),
                round(1.0 / self.config.camera.fps, 9) if wind.strength > 0 else None,
            )
        if key != self._path_key:
            self._path.pose(levels, tree_matrices(self.instances, time_s, wind))
            self._path_key = key
        self.load_seconds += time.perf_counter() - t0
        return self._path

    # -- the frame loop's backend (forest.render.loop) -------------------------------------
    def pose(self, levels: np.ndarray, time_s: float) -> None:
        """Build the Mitsuba scene of this pose (:meth:`scene_at`; kept while the pose stays)."""
        self.scene_at(levels, time_s)

    def samples(self, frame: float, spp: int, seed: int) -> Iterator[PassResult]:
        """The beauty's passes at camera time ``frame``: Mitsuba renders of equal size, consecutive seeds."""
        sensor = self.sensor(frame, spp)
        for i, n in enumerate(self.passes(spp)):
            img = np.asarray(self.mi.render(self._scene, sensor=sensor, spp=n, seed=seed + i), np.float64)[..., :3]
            yield PassResult(spp=n, rgb=img.reshape(-1, 3) * n, alpha=np.zeros(0))

    def first_hits(self, frame: float, levels: np.ndarray) -> Iterator[PassResult]:
        """Up to :data:`COVERAGE_SPP` jittered camera samples per pixel traced by forest_path at the frame's
        centre: coverage, per-sample ids and the denoiser's guides."""
        path = self.path_scene(levels, frame / self.config.camera.fps)
        camera = path_camera(self.config, frame, self.width, self.height)
        yield from path.first_hits(camera, spp=min(self.spp, COVERAGE_SPP), seed=frame_seed(self.config, frame))

    def layers(self, frame: float, levels: np.ndarray) -> dict[str, np.ndarray]:
        """Depth, id and species through the pixel centres, by forest_path at the frame's centre."""
        path = self.path_scene(levels, frame / self.config.camera.fps)
        self._layers = path.layers(path_camera(self.config, frame, self.width, self.height))
        return self._layers

    def post(self, rgb: np.ndarray, alpha: np.ndarray, layers: dict[str, np.ndarray], frame: float) -> np.ndarray:
        """Aerial perspective after the fact (:func:`forest.render.post.apply_haze`), along each pixel's camera
        ray, split between its geometry and its sky by the coverage."""
        if self._path is None or (self.config.render.haze <= 0 and self.config.render.valley_fog is None):
            return rgb
        camera = path_camera(self.config, frame, self.width, self.height)
        return apply_haze(rgb, alpha, layers["depth"], camera, self.config, self._path)

    def frame_lod_counts(self) -> dict[str, int]:
        """Trees per level of detail in the Mitsuba scene just rendered."""
        assert self.graph is not None  # pose built it
        return dict(self.graph.lod_counts)

    def frame(self, frame: float, on_pass: PassCallback | None = None) -> FrameImage:
        """Render one frame (:func:`forest.render.loop.render_frame`); ``on_pass(image so far, passes done,
        passes in the frame)`` is called after every sample pass; calling its first argument gives the running
        mean of the frame's samples;
        the comp AOVs of ``[render] aovs`` (all but the light groups) come attached to the image."""
        return render_frame(self, frame, on_pass)
