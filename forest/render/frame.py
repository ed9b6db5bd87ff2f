"""Rendering the frames of a Scene with Mitsuba's own integrators (``path``/``volpath``).

Per frame f (time t = f / fps seconds):

1. the camera is interpolated along its keys (:func:`forest.camera.camera_at`);
2. every tree gets a level of detail from its distance to the camera
   (:mod:`forest.lod`, through the Scene's plan);
3. with ``shutter`` s > 0 the frame averages K = ``[render] subframes``
   sub-frames at f + s·((k + ½)/K − ½) (:func:`forest.camera.subframe_times`),
   each with its own camera and wind pose — Mitsuba 3 has no animated
   transforms, so motion blur is this box-filtered average over the shutter;
4. each sub-frame renders ⌈spp / K⌉ samples per pixel in passes of equal size
   with consecutive seeds (pass images averaged), which also drives progress
   and the live image of each pass;
5. a 1-sample, box-filtered pass at the frame's centre records per pixel the
   distance to the first hit (``depth``), the tree's ``id`` and its
   ``species`` index (−1 where no tree is hit);
6. optional aerial perspective (:func:`forest.render.post.apply_haze`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..camera import camera_at, subframe_times
from ..errors import ForestError
from ..runtime import mitsuba
from ..scene import Scene
from .instancing import ForestBuilder, tree_matrices
from .materials import MaterialBuilder
from .post import apply_haze, denoise, haze_colour
from .scene import emitter_dicts, sensor_dict, terrain_dict

#: Largest wavefront (pixels × samples) one JIT pass may trace, to bound memory.
JIT_LANES = 1 << 22
#: Samples per pass in scalar_rgb (more passes = finer progress, same image statistics).
SCALAR_PASS_SPP = 8
#: Russian roulette from this path depth on (unbiased; dark foliage paths end early).
RR_DEPTH = 2
#: The id/depth pass looks through at most this many transparent leaf-card texels per pixel
#: (then takes the surface it is on, so dense far foliage still gets a depth and haze).
MAX_ALPHA_SKIPS = 32

#: ``on_pass(image so far, passes done, passes in the frame)``.
PassCallback = Callable[[np.ndarray, int, int], None]


@dataclass(frozen=True)
class FrameSize:
    """Image size, samples per pixel and motion-blur sub-frames of a render."""

    width: int
    height: int
    spp: int
    subframes: int = 1


class FrameRenderer:
    """Renders the frames of one :class:`~forest.scene.Scene` with Mitsuba's own integrators.

    State kept across frames: the materials, the shapegroups and the last
    Mitsuba scene (rebuilt only when the LOD assignment or the wind pose
    changes).
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
        self.terrain = scene.terrain
        self.colour_grid = None if scene.colour is None else scene.colour.rgb
        self.materials = MaterialBuilder(variant, self.colour_grid, self.terrain.extent, self.terrain.height_range)
        self.forest = ForestBuilder(scene, self.materials)
        self.terrain_obj = terrain_dict(config, self.terrain, variant, colour_grid=self.colour_grid)
        self.emitters = emitter_dicts(config, variant)
        # Mitsuba 3.9.1's ``path`` tests shadow rays against whole leaf cards (alpha ignored);
        # ``volpath`` attenuates them by each mask's opacity: exact, but 3–6× slower on foliage.
        self.integrator = {
            "type": "volpath" if rc.alpha_shadows else "path",
            "max_depth": int(rc.max_depth),
            "rr_depth": RR_DEPTH,
        }
        self._scene_key = None
        self._scene = None
        self.graph = None
        self.load_seconds = 0.0
        self.render_seconds = 0.0
        self.lod_counts: dict = {}
        self.max_instanced = 0
        self.max_unique = 0
        self.max_groups = 0

    def restart(self) -> None:
        """Start the statistics of a new render that reuses this renderer (and its built scene)."""
        self.load_seconds = self.render_seconds = 0.0
        self.lod_counts = {}
        g = self.graph
        self.max_instanced, self.max_unique, self.max_groups = (
            (g.instanced_triangles, g.unique_triangles, g.shapegroups) if g is not None else (0, 0, 0)
        )

    # -- scene ---------------------------------------------------------------------
    def scene_at(self, levels: np.ndarray, time_s: float):
        """The scene for an LOD assignment and a wind time (rebuilt only when either changes)."""
        wind = self.config.wind
        key = (levels.tobytes(), round(time_s, 9) if wind.strength > 0 else None)
        if key == self._scene_key:
            return self._scene
        t0 = time.perf_counter()
        self._scene = None
        mats = tree_matrices(self.instances, time_s, wind)
        graph = self.forest.graph(levels, mats)
        scene = {"type": "scene", "integrator": self.integrator, "terrain": self.terrain_obj, **self.emitters}
        scene.update(graph.entries)
        try:
            self._scene = self.mi.load_dict(scene, parallel=True)
        except Exception as e:
            raise ForestError(f"{self.config.path}: cannot build the Mitsuba scene: {str(e).splitlines()[0]}") from None
        del scene
        graph.entries = None  # the dicts are no longer needed: free them before rendering
        self.graph = graph
        self._scene_key = key
        self.max_instanced = max(self.max_instanced, graph.instanced_triangles)
        self.max_unique = max(self.max_unique, graph.unique_triangles)
        self.max_groups = max(self.max_groups, graph.shapegroups)
        self._shape_rows = None
        self.load_seconds += time.perf_counter() - t0
        return self._scene

    def sensor(self, frame: float, spp: int, *, rfilter: str = "box"):
        return self.mi.load_dict(
            sensor_dict(self.config, frame, self.width, self.height, spp, self.variant, rfilter=rfilter)
        )

    def passes(self, spp: int) -> list[int]:
        if self.variant.startswith("scalar"):
            chunk = SCALAR_PASS_SPP
        else:
            chunk = max(1, JIT_LANES // max(1, self.width * self.height))
        n = max(1, math.ceil(spp / chunk))
        base, extra = divmod(spp, n)
        return [base + (1 if i < extra else 0) for i in range(n)]

    # -- passes ----------------------------------------------------------------------
    def beauty(self, scene, sensor, spp: int, seed0: int, tick: Callable[[np.ndarray, int], None]) -> np.ndarray:
        """Mean of ``spp`` samples per pixel in passes; ``tick(pass image, its samples)`` after each pass."""
        acc = np.zeros((self.height, self.width, 3), dtype=np.float64)
        for i, n in enumerate(self.passes(spp)):
            img = np.asarray(self.mi.render(scene, sensor=sensor, spp=n, seed=seed0 + i), dtype=np.float64)[..., :3]
            acc += img * n
            tick(img, n)
        return (acc / spp).astype(np.float32)

    def ids_and_depth(self, scene, frame: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(depth, id, species) per pixel from one primary ray through each pixel centre.

        Depth is the distance along the ray to the first surface (0 = nothing hit);
        the tree is the instance hit, mapped back to its InstanceSet row.
        """
        mi = self.mi
        h, w = self.height, self.width
        sensor = self.sensor(frame, 1, rfilter="box")
        if self.variant.startswith("scalar"):
            # One primary ray per pixel centre.  (Mitsuba's ``aov`` integrator is
            # ~1000× slower here on instanced scenes: measured 3.4 s against 0.05 s
            # for 160×90 pixels over 2 000 instances.)
            depth = np.zeros((h, w), dtype=np.float64)
            rows = np.full((h, w), -1, dtype=np.int64)
            Point2f = mi.Point2f
            aperture = Point2f(0.5, 0.5)
            null = mi.BSDFFlags.Null
            for i in range(h):
                v = (i + 0.5) / h
                for j in range(w):
                    ray, _ = sensor.sample_ray(0.0, 0.5, Point2f((j + 0.5) / w, v), aperture)
                    travelled = 0.0
                    for skip in range(MAX_ALPHA_SKIPS):
                        si = scene.ray_intersect(ray)
                        if not si.is_valid():
                            break
                        bsdf = si.bsdf()
                        if (
                            skip + 1 < MAX_ALPHA_SKIPS
                            and mi.has_flag(bsdf.flags(), null)
                            and float(np.mean(bsdf.eval_null_transmission(si))) > 0.5
                        ):
                            travelled += si.t  # a transparent texel of a leaf card: look past it
                            ray = si.spawn_ray(ray.d)
                            continue
                        # an opaque surface, or the last allowed skip (dense far foliage): take this hit
                        depth[i, j] = travelled + si.t
                        if si.instance is not None:
                            name = si.instance.id()
                            if name.startswith("tree_"):
                                rows[i, j] = int(name[5:])
                        break
        else:
            import drjit as dr

            jj, ii = np.meshgrid(np.arange(w), np.arange(h))
            u = mi.Point2f(mi.Float(((jj + 0.5) / w).ravel()), mi.Float(((ii + 0.5) / h).ravel()))
            ray, _ = sensor.sample_ray(0.0, 0.5, u, mi.Point2f(0.5, 0.5))
            n = h * w
            active = dr.full(mi.Bool, True, n)
            travelled = dr.zeros(mi.Float, n)
            dist = dr.zeros(mi.Float, n)
            reg = dr.zeros(mi.UInt32, n)
            for skip in range(MAX_ALPHA_SKIPS):
                si = scene.ray_intersect(ray, active)
                valid = active & si.is_valid()
                bsdf = si.bsdf(ray)
                tr = bsdf.eval_null_transmission(si, valid)  # Color3f: 1 − opacity for masks, 0 else
                clear = valid & ((tr[0] + tr[1] + tr[2]) > 1.5)
                if skip + 1 == MAX_ALPHA_SKIPS:
                    clear = dr.zeros(mi.Bool, n)  # last skip: take the hit as it is
                stop = valid & ~clear
                dist = dr.select(stop, travelled + si.t, dist)
                reg = dr.select(stop, dr.reinterpret_array(mi.UInt32, si.instance), reg)
                travelled = dr.select(clear, travelled + si.t, travelled)
                ray = dr.select(clear, si.spawn_ray(ray.d), ray)
                active = clear
                dr.eval(dist, reg, travelled, ray, active)
                if not dr.any(active):
                    break
            depth = np.asarray(dist, dtype=np.float64).reshape(h, w)
            shape = self._jit_registry_index(scene, np.asarray(reg).reshape(h, w).astype(np.int64))
            rows = np.full(shape.shape, -1, dtype=np.int64)
            rows[shape >= 0] = self._shape_table(scene)[shape[shape >= 0]]
        tree = rows >= 0
        ids = np.full(rows.shape, -1.0, dtype=np.float64)
        species = np.full(rows.shape, -1.0, dtype=np.float64)
        ids[tree] = self.instances.id[rows[tree]].astype(np.float64)
        species[tree] = self.instances.species[rows[tree]].astype(np.float64)
        return depth.astype(np.float32), ids.astype(np.float32), species.astype(np.float32)

    def _shape_table(self, scene) -> np.ndarray:
        """InstanceSet row of each shape in ``scene.shapes()`` order (−1 for non-trees)."""
        if self._shape_rows is None:
            ids = [s.id() for s in scene.shapes()]
            self._shape_rows = np.array(
                [int(i[5:]) if i.startswith("tree_") else -1 for i in ids] or [-1], dtype=np.int64
            )
        return self._shape_rows

    def _jit_registry_index(self, scene, reg: np.ndarray) -> np.ndarray:
        import drjit as dr

        table = np.asarray(dr.reinterpret_array(self.mi.UInt32, scene.shapes_dr())).astype(np.int64)
        order = np.argsort(table)
        pos = np.searchsorted(table[order], reg)
        pos = np.minimum(pos, len(table) - 1)
        found = (table[order][pos] == reg) & (reg != 0)
        return np.where(found, order[pos], -1)

    # -- one frame ---------------------------------------------------------------------
    def frame(self, frame: float, on_pass: PassCallback | None = None) -> dict:
        """Render one frame: beauty (motion-blur sub-frames averaged), depth, id and species, haze.

        ``on_pass(image so far, passes done, passes in the frame)`` is called after
        every sample pass with the running mean of the frame's samples.
        """
        cam = self.config.camera
        state = camera_at(cam, frame)
        levels = self.scene.lod.levels(self.instances.position, self.instances.species, state.position)
        times = subframe_times(frame, cam.shutter, self.subframes)
        spp_sub = max(1, math.ceil(self.spp / len(times)))
        total = len(times) * len(self.passes(spp_sub))
        running = np.zeros((self.height, self.width, 3), dtype=np.float64)
        taken = [0, 0]  # samples, passes

        def tick(img: np.ndarray, n: int) -> None:
            running[:] += img * n
            taken[0] += n
            taken[1] += 1
            if on_pass is not None:
                on_pass((running / taken[0]).astype(np.float32), taken[1], total)

        acc = np.zeros((self.height, self.width, 3), dtype=np.float64)
        seed = int(self.config.render.seed) * 1_000_003 + int(round(frame * 1000)) * 997
        scene = None
        for k, t in enumerate(times):
            scene = None  # let a superseded scene go before the next is built
            scene = self.scene_at(levels, t / cam.fps)
            sensor = self.sensor(t, spp_sub)
            t0 = time.perf_counter()
            acc += self.beauty(scene, sensor, spp_sub, seed + 101 * k, tick)
            self.render_seconds += time.perf_counter() - t0
        rgb = (acc / len(times)).astype(np.float32)
        scene = None
        scene = self.scene_at(levels, frame / cam.fps)
        t0 = time.perf_counter()
        depth, ids, species = self.ids_and_depth(scene, frame)
        self.render_seconds += time.perf_counter() - t0
        for name, c in self.graph.lod_counts.items():
            self.lod_counts[name] = self.lod_counts.get(name, 0) + c
        rc = self.config.render
        if rc.haze > 0:
            rgb = apply_haze(rgb, depth, depth > 0, rc.haze, haze_colour(self.config))
        denoised = False
        if self.preview:
            d = denoise(rgb)
            if d is not None:
                rgb, denoised = d, True
        far = depth <= 0
        depth = np.where(far, np.float32(cam.far), depth)
        return {
            "rgb": rgb,
            "depth": depth,
            "id": ids,
            "species": species,
            "denoised": denoised,
            "camera": state,
            "levels": levels,
        }
