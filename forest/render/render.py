"""``render_scene``: an InstanceSet rendered with Mitsuba 3 — stills, fly-throughs, motion blur.

Per frame f (time t = f / fps seconds):

1. the camera is interpolated along its keys (:func:`forest.camera.camera_at`);
2. every tree gets a level of detail from its distance to the camera
   (:func:`forest.render.instancing.lod_levels`);
3. with ``shutter`` s > 0 the frame averages K = ``[render] subframes``
   sub-frames at f + s·((k + ½)/K − ½) (:func:`forest.camera.subframe_times`),
   each with its own camera and wind pose — Mitsuba 3 has no animated
   transforms, so motion blur is this box-filtered average over the shutter;
4. each sub-frame renders ⌈spp / K⌉ samples per pixel in passes of equal size
   with consecutive seeds (pass images averaged), which also drives the
   progress bar;
5. a 1-sample, box-filtered pass at the frame's centre records per pixel the
   distance to the first hit (``depth``), the tree's ``id`` and its
   ``species`` index (−1 where no tree is hit);
6. optional aerial perspective: L' = L·e^(−σd) + H·(1 − e^(−σd)) with σ =
   ``[render] haze`` and H = ``haze_colour`` (default: the sky's radiance);
7. the frame is written as a float EXR (beauty RGB plus ``depth``, ``id``
   and ``species`` layers; settings and deterministic scene statistics in the
   header) and an sRGB PNG beside it.
"""

from __future__ import annotations

import math
import resource
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..camera import camera_at, frame_path, parse_frames, subframe_times
from ..errors import ForestError, ParameterError
from ..images import read_map_rgb, write_image, write_multilayer_exr
from ..instances import InstanceSet
from ..runtime import VARIANTS, cuda_available, mitsuba
from ..terrain import load_terrain
from .instancing import ForestBuilder, tree_matrices
from .materials import MaterialBuilder
from .scene import emitter_dicts, sensor_dict, terrain_dict

#: Largest wavefront (pixels × samples) one JIT pass may trace, to bound memory.
JIT_LANES = 1 << 22
#: Samples per pass in scalar_rgb (more passes = finer progress, same image statistics).
SCALAR_PASS_SPP = 8
#: A GPU renders forests up to this many trees faster than the CPU; above it the
#: quadratic instancing cost of the JIT variants in Mitsuba 3.9.1 dominates.
CUDA_MAX_TREES = 2000
PREVIEW_WIDTH = 480
#: Russian roulette from this path depth on (unbiased; dark foliage paths end early).
RR_DEPTH = 2
#: The id/depth pass looks through at most this many transparent leaf-card texels per pixel
#: (then takes the surface it is on, so dense far foliage still gets a depth and haze).
MAX_ALPHA_SKIPS = 32
PREVIEW_SPP = 8


@dataclass
class RenderResult:
    """What a render wrote and what it cost."""

    paths: list[Path]  # every file written (EXR and PNG per frame)
    frames: list[int]
    variant: str
    variant_reason: str
    width: int
    height: int
    spp: int
    subframes: int
    trees: int
    instanced_triangles: int
    unique_triangles: int
    shapegroups: int
    load_seconds: float
    render_seconds: float
    peak_memory_gb: float
    lod_counts: dict = field(default_factory=dict)
    denoised: bool = False
    leaf_model: str = ""

    def summary(self) -> str:
        """One line: trees, instanced and unique triangles, times, peak memory."""
        frames = f"{len(self.frames)} frames" if len(self.frames) > 1 else "1 frame"
        return (
            f"rendered {frames} {self.width}x{self.height} {self.spp} spp ({self.variant}): "
            f"{self.trees:,} trees, {self.instanced_triangles:,} instanced triangles, "
            f"{self.unique_triangles:,} unique, load {self.load_seconds:.1f} s, "
            f"render {self.render_seconds:.1f} s, peak {self.peak_memory_gb:.2f} GB"
        )


def peak_memory_gb() -> float:
    """Peak resident memory of this process (getrusage ru_maxrss, KiB on Linux)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def choose_variant(trees: int, requested: str | None = None, configured: str | None = None) -> tuple[str, str]:
    """The variant to render with, and why.

    An explicit request wins, then ``[render] variant``.  Otherwise: Mitsuba
    3.9.1 builds instanced scenes in time quadratic in the instance count in
    its JIT variants and linear in ``scalar_rgb``; so a GPU (``cuda_ad_rgb``)
    for small forests when one is present, else ``scalar_rgb``.
    """
    for v, why in ((requested, "requested"), (configured, "[render] variant")):
        if v is not None:
            if v not in VARIANTS:
                raise ParameterError("variant", f"must be one of {', '.join(VARIANTS)}, got {v!r}")
            if v == "cuda_ad_rgb" and not cuda_available():
                raise ParameterError("variant", "cuda_ad_rgb needs an NVIDIA GPU and driver, none found")
            if v != "scalar_rgb" and trees > CUDA_MAX_TREES:
                why += (
                    f"; note: {trees:,} instances in a JIT variant build in quadratic time in "
                    "Mitsuba 3.9.1 — scalar_rgb is much faster for this forest"
                )
            return v, why
    if cuda_available() and trees <= CUDA_MAX_TREES:
        return "cuda_ad_rgb", f"GPU found and {trees:,} trees ≤ {CUDA_MAX_TREES:,}"
    return "scalar_rgb", (
        f"{trees:,} trees: instancing is linear in scalar_rgb, quadratic in the JIT variants of Mitsuba 3.9.1"
    )


def _output_paths(output: str | Path) -> tuple[Path, Path]:
    out = Path(output)
    ext = out.suffix.lower()
    if ext == ".exr":
        return out, out.with_suffix(".png")
    if ext == ".png":
        return out.with_suffix(".exr"), out
    raise ForestError(f"-o: {output}: the output must end in .exr (an sRGB .png is written beside it)")


def _resolve_instances(config, instances) -> InstanceSet:
    if isinstance(instances, InstanceSet):
        return instances
    from ..scatter import scene_instances

    result = scene_instances(config, instances)
    return result[0] if isinstance(result, tuple) else result


def _header_value(v):
    if isinstance(v, (bool, np.bool_)):
        return int(v)
    if isinstance(v, (int, np.integer)):
        return int(v) if -(2**31) <= int(v) < 2**31 else str(int(v))
    if isinstance(v, (float, np.floating)):
        return float(v)
    return str(v)


def _denoiser():
    """Intel Open Image Denoise through the optional ``pyoidn`` package, or None."""
    try:
        import pyoidn
    except ImportError:
        return None
    return pyoidn


def denoise(rgb: np.ndarray) -> np.ndarray | None:
    """Denoise a linear HDR image with OIDN's ``RT`` filter; None when OIDN is not installed."""
    oidn = _denoiser()
    if oidn is None:
        return None
    img = np.ascontiguousarray(np.maximum(rgb, 0.0), dtype=np.float32)
    return np.asarray(oidn.denoise(img, hdr=True, quality="high"), dtype=np.float32)


def apply_haze(rgb: np.ndarray, depth: np.ndarray, hit: np.ndarray, sigma: float, colour) -> np.ndarray:
    """Aerial perspective: L·e^(−σd) + H·(1 − e^(−σd)) on pixels that hit a surface.

    The depth comes from one ray through each pixel centre, so a pixel whose
    centre sees the sky may still be partly covered by a distant silhouette
    (a ridge, a tree top).  Such sky pixels next to a hit take the largest
    depth of their 3×3 neighbours, so silhouettes against the sky are hazed
    like the ground behind them instead of leaving a dark fringe.
    """
    if sigma <= 0:
        return rgb
    from scipy.ndimage import maximum_filter

    d = np.where(hit, depth, 0.0)
    edge = ~hit & (maximum_filter(hit.astype(np.uint8), size=3) > 0)
    d = np.where(edge, maximum_filter(d, size=3), d)
    tr = np.exp(-sigma * d)[..., None]
    return (rgb * tr + np.asarray(colour, np.float32) * (1.0 - tr)).astype(np.float32)


class _Renderer:
    """State shared by the frames of one ``render_scene`` call."""

    def __init__(
        self,
        config,
        instances: InstanceSet,
        variant: str,
        library,
        *,
        preview: bool,
        overrides: dict | None,
        progress,
        size: tuple[int, int, int] | None = None,
    ):
        self.config = config
        self.instances = instances
        self.variant = variant
        self.mi = mitsuba(variant)
        self.progress = progress or (lambda f, m="": None)
        rc = config.render
        self.preview = preview
        if preview:
            k = min(1.0, PREVIEW_WIDTH / rc.width)
            self.width, self.height = max(1, round(rc.width * k)), max(1, round(rc.height * k))
            self.spp = min(rc.spp, PREVIEW_SPP)
            self.subframes = 1
        elif size is not None:  # (width, height, spp) of a still at one instant
            self.width, self.height, self.spp = (int(v) for v in size)
            self.subframes = 1
        else:
            self.width, self.height, self.spp = rc.width, rc.height, rc.spp
            self.subframes = rc.subframes if config.camera.shutter > 0 else 1
        self.terrain = load_terrain(config.terrain, config.path)
        self.colour_grid = read_map_rgb(config.maps.colour, what="colour map") if config.maps.colour else None
        self.materials = MaterialBuilder(variant, self.colour_grid, self.terrain.extent, self.terrain.height_range)
        self.forest = ForestBuilder(config, instances, library, self.materials)
        self.terrain_obj = terrain_dict(config, self.terrain, variant, colour_grid=self.colour_grid)
        self.emitters = emitter_dicts(config, variant, overrides)
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
    def beauty(self, scene, sensor, spp: int, seed0: int, tick) -> np.ndarray:
        """The mean of ``spp`` samples per pixel; ``tick(image so far)`` after each pass."""
        acc = np.zeros((self.height, self.width, 3), dtype=np.float64)
        parts = self.passes(spp)
        for i, n in enumerate(parts):
            img = self.mi.render(scene, sensor=sensor, spp=n, seed=seed0 + i)
            acc += np.asarray(img, dtype=np.float64)[..., :3] * n
            tick(acc / sum(parts[: i + 1]))
        return (acc / spp).astype(np.float32)

    def restart(self) -> None:
        """Start the statistics of a new ``render_scene`` call that reuses this renderer."""
        self.load_seconds = self.render_seconds = 0.0
        self.lod_counts = {}
        g = self.graph
        self.max_instanced, self.max_unique, self.max_groups = (
            (g.instanced_triangles, g.unique_triangles, g.shapegroups) if g is not None else (0, 0, 0)
        )

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
    def frame(self, frame: float, tick) -> dict:
        cam = self.config.camera
        state = camera_at(cam, frame)
        levels = self.forest.levels(state.position)
        times = subframe_times(frame, cam.shutter, self.subframes)
        spp_sub = max(1, math.ceil(self.spp / len(times)))
        acc = np.zeros((self.height, self.width, 3), dtype=np.float64)
        seed = int(self.config.render.seed) * 1_000_003 + int(round(frame * 1000)) * 997
        scene = None
        for k, t in enumerate(times):
            scene = None  # let a superseded scene go before the next is built
            scene = self.scene_at(levels, t / cam.fps)
            sensor = self.sensor(t, spp_sub)
            t0 = time.perf_counter()
            # the frame so far: the finished sub-frames and the current one's passes, equally weighted
            acc += self.beauty(
                scene, sensor, spp_sub, seed + 101 * k, lambda img, a=acc, k=k: tick((a + img) / (k + 1))
            )
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
            hc = rc.haze_colour
            if hc is None:
                sky = self.config.lights.sky
                hc = (
                    tuple(sky.radiance * c for c in sky.colour)
                    if sky is not None and sky.kind == "constant"
                    else (0.5, 0.6, 0.75)
                )
            rgb = apply_haze(rgb, depth, depth > 0, rc.haze, hc)
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


def _kept(reuse: dict | None, key: tuple, build):
    """The renderer ``reuse`` keeps for ``key`` (its first three parts compared by identity, the
    rest by value), restarted; else a new one from ``build()``, kept in ``reuse``."""
    old = (reuse or {}).get("key")
    if old is not None and all(a is b for a, b in zip(old[:3], key[:3])) and old[3:] == key[3:]:
        r = reuse["renderer"]  # type: ignore[index]
        r.restart()
        return r
    r = build()
    if reuse is not None:
        reuse.update(key=key, renderer=r)
    return r


def render_image(
    config,
    instances,
    *,
    width: int,
    height: int,
    spp: int,
    variant: str = "scalar_rgb",
    overrides=None,
    library=None,
    reuse: dict | None = None,
) -> np.ndarray:
    """The beauty of frame 1 at ``width``×``height``×``spp`` as an (H, W, 3) linear array, no files, no blur.

    The same scene, materials, LODs and haze as :func:`render_scene`; for
    callers that need the production image itself (look-dev's calibration, the
    job service's quick look).  ``reuse`` as in :func:`render_scene`.
    """
    if library is None:
        from ..library import open_library

        library = open_library()
    inst = _resolve_instances(config, instances)
    r = _kept(
        reuse,
        (config, inst, library, variant, (width, height, spp), overrides),
        lambda: _Renderer(
            config,
            inst,
            variant,
            library,
            preview=False,
            overrides=overrides,
            progress=None,
            size=(width, height, spp),
        ),
    )
    return np.asarray(r.frame(1.0, lambda img: None)["rgb"], np.float64)[..., :3]


def render_scene(
    config,
    *,
    output,
    instances=None,
    variant=None,
    frames=None,
    preview=False,
    overrides=None,
    progress=None,
    library=None,
    announce=None,
    on_pass=None,
    reuse: dict | None = None,
) -> RenderResult:
    """Render the config's forest to ``output`` (EXR + PNG), a still or a frame sequence.

    ``instances``: an :class:`InstanceSet`, a path to a saved one, or None to
    scatter (``forest.scatter.scene_instances``).  ``frames``: None for a still
    at frame 1, a list of frame numbers or a spec like ``"1-120"``; with frames
    ``output`` is a pattern (``out/frame_####.exr``).  ``overrides``: light
    overrides (see :func:`forest.render.scene.emitter_dicts`).
    ``progress(fraction, message)`` is called as passes finish;
    ``announce(variant, reason)`` once the variant is chosen; ``library``
    defaults to :func:`forest.library.open_library`.
    ``on_pass(frame, rgb, done, total)`` after each sample pass: ``rgb`` the
    (H, W, 3) linear float32 mean of the frame's samples so far (before haze and
    denoising), ``done`` of ``total`` passes of the whole call.
    ``reuse``: a dict the caller keeps between calls; the renderer built for the
    same ``config``, ``instances`` and ``library`` objects, variant, preview and
    overrides is kept in it and reused (terrain, materials and the Mitsuba scene
    of the last level-of-detail plan are not rebuilt).
    """
    # Validate everything the render reads before any work.
    config.camera, config.lights, config.render, config.lod, config.wind, config.maps, config.terrain  # noqa: B018
    if isinstance(frames, str):
        frames = parse_frames(frames)
    still = frames is None
    frame_list = [1] if still else [int(f) for f in frames]
    if not frame_list:
        raise ForestError("--frames: no frames to render")
    if still:
        targets = [_output_paths(output)]
    else:
        targets = [_output_paths(frame_path(str(output), f)) for f in frame_list]
        if len({t[0] for t in targets}) != len(targets):
            raise ForestError(f"-o: {output}: every frame needs its own file; put #### in the name")
    inst = _resolve_instances(config, instances)
    chosen, reason = choose_variant(len(inst), variant, config.render.variant)
    if announce is not None:
        announce(chosen, reason)
    if library is None:
        from ..library import open_library

        library = open_library()
    progress = progress or (lambda f, m="": None)
    progress(0.0, "building scene")
    r = _kept(
        reuse,
        (config, inst, library, chosen, bool(preview), overrides),
        lambda: _Renderer(config, inst, chosen, library, preview=preview, overrides=overrides, progress=progress),
    )
    n_sub = r.subframes
    total = len(frame_list) * n_sub * len(r.passes(max(1, math.ceil(r.spp / n_sub))))
    done = [0]
    written: list[Path] = []
    denoised = False

    for fi, (f, (exr, png)) in enumerate(zip(frame_list, targets)):

        def tick(img, fi=fi):
            done[0] += 1
            progress(done[0] / total, f"frame {frame_list[fi]} ({fi + 1}/{len(frame_list)})")
            if on_pass is not None:
                on_pass(frame_list[fi], img.astype(np.float32), done[0], total)

        out = r.frame(float(f), tick)
        denoised |= out["denoised"]
        g = r.graph
        cam = out["camera"]
        attrs = {
            "forest:config": config.name,
            "forest:seed": int(config.seed),
            "forest:frame": int(f),
            "forest:variant": chosen,
            "forest:spp": r.spp,
            "forest:subframes": n_sub,
            "forest:shutter": float(config.camera.shutter),
            "forest:max_depth": int(config.render.max_depth),
            "forest:render_seed": int(config.render.seed),
            "forest:preview": bool(preview),
            "forest:denoised": bool(out["denoised"]),
            "forest:leaf_model": r.materials.leaf_model,
            "forest:trees": g.trees,
            "forest:instanced_triangles": g.instanced_triangles,
            "forest:unique_triangles": g.unique_triangles,
            "forest:shapegroups": g.shapegroups,
            "forest:lod": ", ".join(f"{k}={v}" for k, v in g.lod_counts.items()),
            "forest:lod_distances": ", ".join(f"{d:g}" for d in config.lod.distances),
            "forest:camera_position": ", ".join(f"{x:.4f}" for x in cam.position),
            "forest:camera_target": ", ".join(f"{x:.4f}" for x in cam.target),
            "forest:fov": float(cam.fov),
            "forest:wind_strength": float(config.wind.strength),
            "forest:haze": float(config.render.haze),
            "forest:layers": "RGB beauty (linear); depth.Z distance to the first hit in metres (far clip where "
            "nothing is hit); id.Z tree id (-1 none); species.Z species index (-1 none)",
        }
        attrs = {k: _header_value(v) for k, v in attrs.items()}
        write_multilayer_exr(
            exr, {"": out["rgb"], "depth": out["depth"], "id": out["id"], "species": out["species"]}, attributes=attrs
        )
        write_image(png, out["rgb"])
        written += [exr, png]
    progress(1.0, "done")
    return RenderResult(
        paths=written,
        frames=frame_list,
        variant=chosen,
        variant_reason=reason,
        width=r.width,
        height=r.height,
        spp=r.spp,
        subframes=n_sub,
        trees=len(inst),
        instanced_triangles=r.max_instanced,
        unique_triangles=r.max_unique,
        shapegroups=r.max_groups,
        load_seconds=r.load_seconds,
        render_seconds=r.render_seconds,
        peak_memory_gb=peak_memory_gb(),
        lod_counts=r.lod_counts,
        denoised=denoised,
        leaf_model=r.materials.leaf_model,
    )
