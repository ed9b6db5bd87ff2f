"""The forest path tracer's driver: a reusable :class:`PathScene` and :func:`render_frame`.

Building the Mitsuba traversal scene is the expensive step, so a
:class:`PathScene` keeps it (and forest's part buffers, materials, textures and
lights) across sample passes, cameras and frames; :meth:`PathScene.pose`
rebuilds only the traversal scene for a new level-of-detail plan or new tree
transforms (wind, a motion-blur sub-frame).

An image is rendered in *passes* of at most :data:`MAX_LANES` paths (pixels ×
samples) so memory stays bounded at any resolution.  Within a pass the paths
of pixel (x, y) are the consecutive lanes ``(y·W + x)·s … + s − 1``, which is
the layout Mitsuba's stratified samplers (``multijitter``, ``orthogonal``,
``ldsampler``) stratify over once told so (``set_samples_per_wavefront(s)``:
the s lanes are one sequence; without it each lane is a sequence of its own
and the sampler is no better than ``independent`` — on a 2 000-tree frame at
16 spp the stratified one leaves 2.4× less variance); each pass has its own seed, derived from the
render seed by ``np.random.SeedSequence([seed, SEED_TAG, pass])``.  Samples
are summed per pixel in numpy (float64, fixed order) rather than splatted
with atomics, so the same inputs and seed give the same image bit for bit.
:meth:`PathScene.passes` queues pass k on the device before it hands back
pass k − 1, so the caller's host work on one pass runs beside the next
pass's kernel.

Parameters (``PathScene.params``, drjit values the caller may change or
differentiate between renders): ``colour_grid`` (TensorXf (H, W, 3)),
``sun_irradiance`` (disc sun), ``sky_radiance`` (constant sky),
``sky_scale`` (envmap / sunsky sky), ``sun_scale`` (sunsky sun), ``sky_zenith`` and
``sky_horizon`` (gradient sky), each RGB; ``leaf_tint`` (Float, S·3: an RGB multiplier
of each species' leaf albedo) and ``ground_tint`` (RGB, the terrain's albedo);
with a haze (:mod:`.haze`) also ``haze_density``, ``haze_height``,
``haze_anisotropy`` (Float) and ``haze_colour`` (RGB).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ...errors import ForestError
from ...progress import scaled
from ...runtime import mitsuba
from .arrays import mappable, opaque, owned
from .emitters import LightSet, make_backdrop, make_lights, sky_mean_radiance
from .geometry import ForestGeometry, FrameStats, PartArrays, TraversalScene, available_bytes, memory_plan
from .haze import HazeInputs, HazeModel
from .inputs import PathCamera, PathInputs
from .integrator import LAYER_ALPHA, NO_HIT, PathKernel, integrator_class
from .lens import thin_lens_rays
from .materials import FarCoverArrays, MaterialArrays, MaterialStore, RowTints, TerrainMap, world_map_texture

#: Largest number of paths (pixels × samples) traced in one pass on the CPU (``llvm_ad_rgb``).
MAX_LANES = 1 << 21
#: The same on the GPU (``cuda_ad_rgb``): larger passes keep a GPU busy and halve the passes' fixed host-side
#: cost each time they double (``bench/bench_gpu.py``); 8 M paths hold a few GB of loop state on the device.
GPU_MAX_LANES = 1 << 23
SEED_TAG = 0x5041_5448  # "PATH"
JIT_VARIANTS = ("llvm_ad_rgb", "cuda_ad_rgb")
#: Memory kept free beside the traversal scene for the render's film, wavefronts, kernels and the rest of the
#: process (:func:`memory_headroom`): the pre-flight model's per-pixel and per-lane costs and
#: :data:`MEMORY_MARGIN`, at most :data:`MEMORY_HEADROOM` — so a small image still renders in a 1 GiB cgroup.
MEMORY_HEADROOM = 1 << 30
MEMORY_MARGIN = 256 << 20


def memory_headroom(width: int, height: int, spp: int) -> int:
    """Bytes :meth:`PathScene.check_memory` keeps free beside the traversal scene for a ``width``×``height`` render."""
    from ...preflight import BYTES_PER_LANE, BYTES_PER_PIXEL

    pixels = int(width) * int(height)
    passes = BYTES_PER_PIXEL["jit"] * pixels + BYTES_PER_LANE * min(MAX_LANES, pixels * max(1, int(spp)))
    return min(MEMORY_HEADROOM, MEMORY_MARGIN + passes)


def pass_seed(seed: int, k: int) -> int:
    """The 32-bit seed of sample pass ``k`` of a render seeded with ``seed``."""
    return int(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, SEED_TAG, int(k)]).generate_state(1)[0])


def sampler_count(mi: Any, kind: str, spp: int) -> int:
    """The samples per pixel Mitsuba's sampler ``kind`` takes when asked for ``spp``.

    A stratified sampler rounds its count to its grid (``multijitter``: 34 → 35 = 5 × 7)
    and logs a warning when it does; the count is asked for once, quietly, and the
    sampler a pass uses is then made with the count it keeps (no warning per pass).
    """
    key = (mi.variant(), kind, int(spp))
    if key not in _SAMPLER_COUNTS:
        logger = mi.logger()
        level = logger.log_level()
        logger.set_log_level(mi.LogLevel.Error)
        try:
            _SAMPLER_COUNTS[key] = int(mi.load_dict({"type": kind, "sample_count": int(spp)}).sample_count())
        finally:
            logger.set_log_level(level)
    return _SAMPLER_COUNTS[key]


_SAMPLER_COUNTS: dict[tuple[str, str, int], int] = {}


def max_lanes(variant: str) -> int:
    """Paths one pass of ``variant`` traces at most."""
    return GPU_MAX_LANES if variant == "cuda_ad_rgb" else MAX_LANES


def pixel_sums(mi: Any, value: Any, spp: int, pixels: int) -> np.ndarray:
    """Per-pixel sums of a per-lane value (lanes pixel-major, ``spp`` consecutive per pixel), summed on the device.

    ``value`` is a Float or a 3-vector; returns (pixels,) or (pixels, 3) float32, the device's sums as they
    are (a view of its memory: the caller adds them into float64).  A component that drjit holds as one
    broadcast literal is widened first (a block sum of a literal is the literal).
    """
    return _host_sums(_device_sums(mi, value, spp, pixels))


def _device_sums(mi: Any, value: Any, spp: int, pixels: int) -> tuple[Any, int]:
    """:func:`pixel_sums` up to the device: (a Float of the sums, components), a 3-vector interleaved
    (x₀ y₀ z₀ x₁ …) by ``dr.ravel`` so the host takes it as one (pixels, 3) block; not yet evaluated."""
    import drjit as dr

    n = pixels * spp
    comps = [value] if dr.depth_v(value) == 1 else [value[i] for i in range(len(value))]
    sums = []
    for c in comps:
        c = mi.Float(c)
        if dr.width(c) == 1 and n > 1:
            c = c + dr.zeros(mi.Float, n)  # a broadcast literal, widened to one value per lane
        sums.append(dr.block_sum(c, spp) if spp > 1 else c)
    if len(sums) == 1:
        return sums[0], 1
    return dr.ravel(mi.Vector3f(*sums)), 3


def _host_sums(sums: tuple[Any, int]) -> np.ndarray:
    """Evaluated device sums (:func:`_device_sums`) as a (pixels,) or (pixels, 3) float32 view of the device's
    memory.  Not copied to float64 here: a fresh 48 MB array per pass of a 1080p frame cost 0.1 s in page
    faults alone, where the caller's running float64 sums take a float32 addend at the same precision."""
    value, comps = sums
    a = np.asarray(value)
    return a if comps == 1 else a.reshape(-1, comps)


def split_passes(width: int, height: int, spp: int, max_lanes: int | None = None) -> list[int]:
    """Samples per pixel of each pass: as equal as possible, each pass ≤ ``max_lanes`` (:data:`MAX_LANES`) paths."""
    per = max(1, (MAX_LANES if max_lanes is None else max_lanes) // max(1, width * height))
    n = max(1, math.ceil(spp / per))
    base, extra = divmod(spp, n)
    return [base + (1 if i < extra else 0) for i in range(n)]


def sensor_dict(mi: Any, camera: PathCamera) -> dict[str, Any]:
    """A Mitsuba ``perspective`` sensor for ``camera`` (horizontal fov, box filter)."""
    return {
        "type": "perspective",
        "fov": float(camera.fov),
        "fov_axis": "x",
        "near_clip": float(camera.near),
        "far_clip": float(camera.far),
        "to_world": mi.ScalarTransform4f(np.asarray(camera.to_world, dtype=np.float64)),
        "film": {
            "type": "hdrfilm",
            "width": int(camera.width),
            "height": int(camera.height),
            "pixel_format": "rgba",
            "rfilter": {"type": "box"},
        },
        "sampler": {"type": "independent", "sample_count": 1},
    }


@dataclass
class PassResult:
    """One sample pass, per pixel (row-major, H·W rows): sums over its ``spp`` samples, and per-sample first hits.

    ``rows`` (H·W, spp) is the row of the surface each sample's camera ray met
    first (a tree row < N, the identity row N for world-space parts) or
    :data:`~forest.render.path.integrator.NO_HIT`.  A pass that traced only some pixels (adaptive sampling,
    :meth:`PathScene.sample_pass` with ``pixels``) has ``counts``: its sums are still per pixel of the whole
    image, 0 where it traced nothing.
    """

    spp: int
    rgb: np.ndarray  # (H·W, 3) summed (float32 from the device: add it into float64)
    alpha: np.ndarray  # (H·W,) samples whose camera ray hit a surface
    rows: np.ndarray | None = None  # (H·W, spp) uint32
    albedo: np.ndarray | None = None  # (H·W, 3) summed
    normal: np.ndarray | None = None  # (H·W, 3) summed
    segments: np.ndarray | None = None  # (H·W, spp) uint32: ray segments each path traced (beauty passes only)
    groups: dict[str, np.ndarray] | None = None  # light group → (H·W, 3) summed; Σ groups = rgb (``groups=True``)
    counts: np.ndarray | None = None  # (H·W,) samples per pixel when only some pixels were traced (adaptive), else None
    lum2: np.ndarray | None = None  # (H·W,) Σ of the samples' squared luminance Y² (adaptive sampling's error)


@dataclass
class PathImage:
    """A rendered frame: linear RGB and coverage (fraction of a pixel's paths whose camera ray hit a surface)."""

    rgb: np.ndarray  # (H, W, 3) float32
    alpha: np.ndarray  # (H, W) float32
    spp: int
    seconds: float


class PathScene:
    """A forest ready to render with the forest path tracer in a JIT variant (see the module docstring)."""

    def __init__(
        self, inputs: PathInputs, variant: str = "llvm_ad_rgb", progress: Callable[[float, str], None] | None = None
    ):
        """Build the scene's buffers, materials and lights and load its first pose; ``progress(fraction, message)``
        follows the build (the terrain, then :class:`TraversalScene`'s steps), ending short of 1 (the caller's)."""
        if variant not in JIT_VARIANTS:
            raise ForestError(f"--variant: the forest path tracer runs in {' or '.join(JIT_VARIANTS)}, not {variant}")
        inputs.validate()
        self.variant = variant
        self.max_lanes = max_lanes(variant)
        self.mi = mi = mitsuba(variant)
        self.inputs = inputs
        self.materials = MaterialStore()
        if progress is not None:
            progress(0.0, "geometry: terrain and surfaces")
        self.geometry = ForestGeometry(inputs, self.materials)
        self.extent = inputs.grid_extent()
        self.lights = make_lights(mi, inputs.sun, inputs.sky)
        self.backdrop = make_backdrop(mi, inputs.sun, inputs.sky, self.lights)
        self.params: dict[str, Any] = {}
        for light in self.lights:
            self.params[light.param] = opaque(mi.Color3f, *light.initial)
        leaf, ground = inputs.tints()
        self.params["leaf_tint"] = owned(mi.Float, leaf.astype(np.float32).ravel())
        self.params["ground_tint"] = opaque(mi.Color3f, *ground)
        #: Each row's colour jitter and bark factor (the trees', then 1 for the identity row), or None: see
        #: ``.materials.RowTints``.
        self.row_tint = RowTints.build(mi, inputs.tree_tint, inputs.bark_tint)
        if inputs.colour_grid is not None:
            self.params["colour_grid"] = owned(mi.TensorXf, np.asarray(inputs.colour_grid, dtype=np.float32))
        self.haze: HazeInputs | None = None
        if inputs.haze is not None:
            haze = inputs.haze
            if haze.colour is None:
                haze = replace(haze, colour=tuple(float(c) for c in sky_mean_radiance(self.lights)))
            self.haze = haze
            self.params.update(HazeModel.initial_params(mi, haze))
        tc = inputs.terrain_map_array()  # RGB, and the water coverage as a fourth channel where there is water
        terrain_extent = inputs.terrain_extent or self.extent
        far = None if inputs.far_cover is None else FarCoverArrays.build(mi, inputs.far_cover)
        self.terrain_map = (
            TerrainMap(world_map_texture(mi, tc), tuple(float(v) for v in terrain_extent), far, inputs.sea_map())
            if tc.ndim == 3
            else None
        )
        self.traversal: TraversalScene | None = None
        self._parts: PartArrays | None = None
        self._mats: MaterialArrays | None = None
        self._mats_count = 0
        self._sensors: dict[bytes, Any] = {}
        self.load_seconds = 0.0
        self.pose(inputs.levels, inputs.matrices, progress=None if progress is None else scaled(progress, 0.05, 0.98))

    # -- scene state ----------------------------------------------------------------------
    def activate(self) -> None:
        """Make this scene's variant Mitsuba's current one (``mi.Float`` etc. follow the current variant)."""
        mitsuba(self.variant)

    def pose(
        self,
        levels: np.ndarray | None = None,
        matrices: np.ndarray | None = None,
        progress: Callable[[float, str], None] | None = None,
        solid: np.ndarray | None = None,
    ) -> None:
        """Rebuild the traversal scene for new levels of detail, tree transforms and/or solid cards (``solid``
        (N,) bool, the trees whose cut-out leaf cards are drawn solid; None: the inputs'); ``progress``: its
        steps, as :class:`TraversalScene` reports them, then the part and material arrays."""
        self.activate()
        solid = self.inputs.solid if solid is None else np.asarray(solid, bool)
        levels = self.inputs.levels if levels is None else np.asarray(levels)
        matrices = self.inputs.matrices if matrices is None else np.asarray(matrices)
        n = self.geometry.n_trees
        if levels.shape != (n,) or matrices.shape != (n, 4, 4):
            raise ForestError(f"path scene: pose needs {n} levels and ({n}, 4, 4) matrices")
        self.traversal = None  # free the previous scene before building the next
        if solid is not None and solid.shape != (n,):
            raise ForestError(f"path scene: pose needs {n} solid-card flags")
        self.check_memory(levels, solid)
        t0 = time.perf_counter()
        self.traversal = TraversalScene(
            self.mi, self.geometry, levels, matrices, None if progress is None else scaled(progress, 0.0, 0.95), solid
        )
        if progress is not None:
            progress(0.95, "part buffers and materials")
        if self._parts is None or self._parts.count != len(self.geometry.parts.triangles):
            self._parts = PartArrays(self.mi, self.geometry.parts)
        if self._mats is None or self._mats_count != len(self.materials):
            self._mats = MaterialArrays.build(self.mi, self.materials.table())
            self._mats_count = len(self.materials)
        self.levels = np.asarray(levels)
        self.load_seconds += time.perf_counter() - t0

    def check_memory(self, levels: np.ndarray, solid: np.ndarray | None = None) -> None:
        """Fail before loading when the instance records alone would not fit in memory (llvm only)."""
        if self.variant != "llvm_ad_rgb":
            return
        instances, flat, need = memory_plan(self.geometry, np.asarray(levels), solid)
        have = available_bytes()  # the machine's and this process's cgroups' room (forest.memory)
        camera = self.inputs.camera
        headroom = memory_headroom(camera.width, camera.height, self.inputs.spp)
        image = headroom - MEMORY_MARGIN
        if have is not None and need > have - headroom and need <= have - MEMORY_MARGIN and image > need:
            # The trees alone fit and the image's film and sample passes are the larger share: the image is the cause.
            raise ForestError(
                f"[render] width, height: a {camera.width}x{camera.height} image needs about "
                f"{image / 2**30:.1f} GB for its film and sample passes beside the "
                f"{need / 2**30:.1f} GB of {instances:,} instanced trees, and {have / 2**30:.1f} GB is available; "
                "render a smaller image"
            )
        if have is not None and need > have - headroom:
            setting = self.inputs.lod_setting
            advice = {
                "pixels": "raise the [lod] pixels thresholds",
                "auto": "turn level of detail on (leave [lod] auto out)",
            }.get(setting, "bring the level-of-detail distances closer")
            raise ForestError(
                f"[lod] {setting}: {instances:,} instanced trees and {flat:,} merged far-level triangles need about "
                f"{need / 2**30:.1f} GB, {max(have - headroom, 0) / 2**30:.1f} GB is available; {advice} "
                "so more trees use the merged far level"
            )

    @property
    def stats(self) -> FrameStats:
        """The traversal's :class:`~forest.render.path.geometry.FrameStats` (trees, instances, triangles, load time)."""
        assert self.traversal is not None
        return self.traversal.stats

    def kernel(self, *, max_depth: int | None = None) -> PathKernel:
        """The render kernel over the current pose and parameter values (gradients kept)."""
        self.activate()
        mi = self.mi
        assert self.traversal is not None and self._parts is not None and self._mats is not None
        import drjit as dr

        grid = self.params.get("colour_grid")
        grid_tex = None
        if grid is not None:
            grid_tex = world_map_texture(mi, grid, differentiable=dr.grad_enabled(grid))
        g = self.params["ground_tint"]
        table = dr.concat([self.params["leaf_tint"], g.x, g.y, g.z])
        mats = self._mats.tinted_colours(mi, table)
        lights = LightSet(mi, self.lights, self.params, self.backdrop)
        haze = None
        if self.haze is not None:
            # A haze of density 0 costs nothing unless its parameters are being differentiated.
            attached = any(dr.grad_enabled(self.params[k]) for k in HazeModel.PARAMS)
            if attached or self.haze.fog is not None or float(np.asarray(self.params["haze_density"]).ravel()[0]) > 0.0:
                haze = HazeModel(mi, self.haze, self.params, lights.sun())
        return PathKernel(
            mi,
            self.traversal,
            self._parts,
            mats,
            grid=grid_tex,
            terrain_map=self.terrain_map,
            extent=self.extent,
            lights=lights,
            max_depth=int(self.inputs.max_depth if max_depth is None else max_depth),
            rr_depth=int(self.inputs.rr_depth),
            haze=haze,
            water_ripple=None if self.inputs.terrain_water is None else float(self.inputs.water_ripple),
            row_tint=self.row_tint,
        )

    def integrator(self, *, max_depth: int | None = None) -> Any:
        """A ``forest_path`` Mitsuba integrator bound to this scene, for ``mi.render(self.traversal.scene, ...)``.

        ``mi.render`` splats with Mitsuba's film (atomic adds): use :meth:`render`
        where bit-identical images matter.
        """
        cls = integrator_class(self.mi)
        return cls(self.mi.Properties()).bind(self.kernel(max_depth=max_depth))

    def scene_parameters(self) -> Any:
        """:attr:`params` as a read-only ``mi.SceneParameters`` view, the ``params`` argument ``mi.render`` takes."""
        self.activate()
        return self.mi.SceneParameters({k: (v, None, None, 0) for k, v in self.params.items()})

    def sensor(self, camera: PathCamera | None = None) -> Any:
        """The Mitsuba sensor of ``camera`` (default: the inputs' camera), cached per pose, fov and size."""
        camera = camera or self.inputs.camera
        key = (
            np.asarray(camera.to_world, np.float64).tobytes()
            + repr((camera.fov, camera.width, camera.height, camera.near, camera.far)).encode()
        )
        if key not in self._sensors:
            if len(self._sensors) > 8:
                self._sensors.clear()
            self._sensors[key] = self.mi.load_dict(sensor_dict(self.mi, camera))
        return self._sensors[key]

    # -- sampling -------------------------------------------------------------------------
    def _camera_rays(self, camera: PathCamera, spp: int, seed: int, pixels: Any = None) -> tuple[Any, Any, int]:
        """(sampler, rays, spp actually used) for one pass: lanes pixel-major, ``spp`` consecutive per pixel;
        ``pixels`` (UInt32 row-major indices) traces only those pixels (adaptive sampling), in that order."""
        import drjit as dr

        mi = self.mi
        spp = sampler_count(mi, self.inputs.sampler, spp)
        sampler = mi.load_dict({"type": self.inputs.sampler, "sample_count": spp})
        # The pixel's spp lanes are one sequence: without this every lane is a sequence of its own, sample 0,
        # and a stratified sampler degenerates to independent sampling.
        sampler.set_samples_per_wavefront(spp)
        w, h = int(camera.width), int(camera.height)
        n = (w * h if pixels is None else dr.width(pixels)) * spp
        # An opaque seed: one compiled kernel serves every pass and render (a literal would recompile).
        sampler.seed(dr.opaque(mi.UInt32, seed & 0xFFFFFFFF), n)
        idx = dr.arange(mi.UInt32, n)
        pixel = idx // spp if pixels is None else dr.gather(mi.UInt32, pixels, idx // spp)
        x = mi.Float(pixel % w)
        y = mi.Float(pixel // w)
        u = sampler.next_2d()
        pos = mi.Point2f((x + u.x) / w, (y + u.y) / h)
        ray, _ = self.sensor(camera).sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
        if camera.lens_radius > 0.0:  # depth of field: its own sampler dimension, drawn only then (.lens)
            ray = thin_lens_rays(mi, camera, ray, sampler.next_2d())
        return sampler, ray, spp

    def passes(
        self,
        camera: PathCamera | None = None,
        *,
        spp: int | None = None,
        seed: int | None = None,
        max_depth: int | None = None,
        aux: bool = False,
        groups: bool = False,
    ) -> Iterator[PassResult]:
        """Render the beauty pass by pass (primal only): one :class:`PassResult` per sample pass.

        Pass k traces ``split_passes(...)[k]`` samples per pixel seeded with
        :func:`pass_seed` (seed, k) (:meth:`sample_pass`), so the passes of a render are the same
        whether they are consumed one by one or summed by :meth:`render`.
        ``aux`` also returns each sample's first hit (row), albedo and normal; ``groups`` (with ``aux``)
        the beauty split by light group (:meth:`PathKernel.sample`): ``rgb`` = Σ ``groups`` per pixel up to
        float rounding, the same samples summed the same way.
        """
        import drjit as dr

        camera = camera or self.inputs.camera
        spp = int(self.inputs.spp if spp is None else spp)
        seed = int(self.inputs.seed if seed is None else seed)
        w, h = int(camera.width), int(camera.height)
        kernel = self.kernel(max_depth=max_depth)
        # Pass k runs on the device while the caller adds up pass k − 1 (dr.eval returns once the kernel is
        # queued; reading a pass's sums waits for it), so the host's share of a pass costs no wall time.
        with dr.suspend_grad():
            collect: Callable[[], PassResult] | None = None
            for k, n in enumerate(split_passes(w, h, spp, self.max_lanes)):
                done = None if collect is None else collect()
                collect = self.launch_pass(kernel, camera, n, pass_seed(seed, k), aux=aux, groups=groups)
                if done is not None:
                    yield done
            if collect is not None:
                yield collect()

    def sample_pass(
        self,
        kernel: PathKernel,
        camera: PathCamera,
        spp: int,
        seed: int,
        *,
        pixels: np.ndarray | None = None,
        aux: bool = False,
        groups: bool = False,
        luma: tuple[float, float, float] | None = None,
    ) -> PassResult:
        """One sample pass of ``kernel``: ``spp`` samples through every pixel, or only through ``pixels``
        (row-major indices, adaptive sampling), seeded ``seed``; call it under ``dr.suspend_grad()``.

        The sums are per pixel of the whole image either way: with ``pixels`` the untraced pixels' sums are 0,
        their ``rows`` :data:`NO_HIT`, and ``counts`` holds each pixel's samples (``spp`` used where traced,
        0 elsewhere).  ``luma`` = (w_R, w_G, w_B) also sums each sample's squared luminance
        Y² = (w_R R + w_G G + w_B B)² into ``lum2`` (the second moment of adaptive sampling's error estimate).
        ``aux`` and ``groups`` as in :meth:`passes`.
        """
        return self.launch_pass(kernel, camera, spp, seed, pixels=pixels, aux=aux, groups=groups, luma=luma)()

    def launch_pass(
        self,
        kernel: PathKernel,
        camera: PathCamera,
        spp: int,
        seed: int,
        *,
        pixels: np.ndarray | None = None,
        aux: bool = False,
        groups: bool = False,
        luma: tuple[float, float, float] | None = None,
    ) -> Callable[[], PassResult]:
        """:meth:`sample_pass` in two steps: queue the pass's kernels on the device and return at once; the
        returned function waits for them and gives the :class:`PassResult`."""
        import drjit as dr

        mi = self.mi
        n = int(camera.width) * int(camera.height)
        m = n if pixels is None else len(pixels)
        lanes = None if pixels is None else mi.UInt32(mappable(np.asarray(pixels, np.uint32)))
        sampler, ray, used = self._camera_rays(camera, spp, seed, pixels=lanes)
        out = kernel.sample(dr.ADMode.Primal, sampler, ray, None, None, mi_bool(mi, True), aux=aux, groups=groups)
        # A sample that is not finite (NaN or inf: 1 pixel of 230 400 in a 130 000-tree frame at 16 spp) would
        # poison its pixel's sum; it counts as black, so one bad path costs its pixel one sample, not the pixel.
        L = dr.select(dr.isfinite(out[0][0] + out[0][1] + out[0][2]), out[0], 0.0)
        covered = mi_float(mi, out[1])
        extra = dict(out[3]) if aux else {}
        split = extra.pop("groups", {})
        moments = [] if luma is None else [L[0] * luma[0] + L[1] * luma[1] + L[2] * luma[2]]
        dr.eval(L, covered, *moments, *extra.values(), *split.values())  # one kernel for all outputs

        # Per-pixel sums on the device: only pixels, not samples, cross to the host (ids excepted).
        device = {"rgb": _device_sums(mi, L, used, m), "alpha": _device_sums(mi, covered, used, m)}
        if aux:
            device["albedo"] = _device_sums(mi, extra["albedo"], used, m)
            device["normal"] = _device_sums(mi, extra["normal"], used, m)
        if moments:
            device["lum2"] = _device_sums(mi, moments[0] * moments[0], used, m)
        device_groups = {g: _device_sums(mi, v, used, m) for g, v in split.items()}
        dr.eval(*(v for v, _ in (*device.values(), *device_groups.values())))

        def sums(value: tuple[Any, int]) -> np.ndarray:
            a = _host_sums(value)
            if pixels is None:
                return a
            full = np.zeros((n, *a.shape[1:]), a.dtype)
            full[pixels] = a
            return full

        def per_sample(value: Any, fill: int) -> np.ndarray:
            a = np.asarray(value, np.uint32).reshape(m, used)
            if pixels is None:
                return a
            full = np.full((n, used), fill, np.uint32)
            full[pixels] = a
            return full

        def collect() -> PassResult:
            result = PassResult(spp=used, rgb=sums(device["rgb"]), alpha=sums(device["alpha"]))
            if aux:
                result.rows = per_sample(extra["row"], NO_HIT)
                result.albedo = sums(device["albedo"])
                result.normal = sums(device["normal"])
                result.segments = per_sample(extra["segments"], 0)
            if device_groups:
                result.groups = {g: sums(v) for g, v in device_groups.items()}
            if moments:
                result.lum2 = sums(device["lum2"])
            if pixels is not None:
                result.counts = np.zeros(n)
                result.counts[pixels] = used
            return result

        return collect

    def render(
        self,
        camera: PathCamera | None = None,
        *,
        spp: int | None = None,
        seed: int | None = None,
        max_depth: int | None = None,
        progress: Callable[[float], None] | None = None,
    ) -> PathImage:
        """Render the beauty and coverage in passes (primal only; see :meth:`render_forward` for gradients).

        ``progress(fraction)`` is called after each pass.
        """
        camera = camera or self.inputs.camera
        spp_ = int(self.inputs.spp if spp is None else spp)
        w, h = int(camera.width), int(camera.height)
        acc = np.zeros((h * w, 4), np.float64)
        total = 0
        t0 = time.perf_counter()
        n_passes = len(split_passes(w, h, spp_, self.max_lanes))
        for k, p in enumerate(self.passes(camera, spp=spp_, seed=seed, max_depth=max_depth)):
            acc[:, :3] += p.rgb
            acc[:, 3] += p.alpha
            total += p.spp
            if progress is not None:
                progress((k + 1) / n_passes)
        img = (acc / total).reshape(h, w, 4)
        return PathImage(
            rgb=img[..., :3].astype(np.float32),
            alpha=img[..., 3].astype(np.float32),
            spp=total,
            seconds=time.perf_counter() - t0,
        )

    def first_hits(self, camera: PathCamera | None = None, *, spp: int = 1, seed: int = 0) -> Iterator[PassResult]:
        """Per sample, what the camera ray meets first (cut-outs passed stochastically), pass by pass.

        The coverage, per-sample ids and denoiser guides of a frame whose beauty
        another renderer made (``scalar_rgb``): :class:`PassResult` with ``rows``,
        ``alpha``, ``albedo`` and ``normal`` (``rgb`` is zero).
        """
        import drjit as dr

        camera = camera or self.inputs.camera
        w, h = int(camera.width), int(camera.height)
        kernel = self.kernel()
        with dr.suspend_grad():
            for k, n in enumerate(split_passes(w, h, int(spp), self.max_lanes)):
                sampler, ray, used = self._camera_rays(camera, n, pass_seed(int(seed), k))
                row, albedo, normal = kernel.first_hit(sampler, ray, mi_bool(self.mi, True))
                dr.eval(row, albedo, normal)
                rows = np.asarray(row, np.uint32).reshape(h * w, used)
                yield PassResult(
                    spp=used,
                    rgb=np.zeros((h * w, 3)),
                    alpha=(rows != NO_HIT).sum(axis=1).astype(np.float64),
                    rows=rows,
                    albedo=pixel_sums(self.mi, albedo, used, h * w),
                    normal=pixel_sums(self.mi, normal, used, h * w),
                )

    # -- derivatives ------------------------------------------------------------------------
    def _passes(self, camera: PathCamera, spp: int, seed: int) -> Iterator[tuple[int, Any, Any, int]]:
        """(pass index, sampler, rays, samples per pixel) of each sample pass of a render."""
        w, h = int(camera.width), int(camera.height)
        for k, n in enumerate(split_passes(w, h, spp, self.max_lanes)):
            sampler, ray, used = self._camera_rays(camera, n, pass_seed(seed, k))
            yield k, sampler, ray, used

    def _spp_total(self, camera: PathCamera, spp: int) -> int:
        """Samples per pixel a render of ``spp`` actually takes (the sampler may round each pass)."""
        mi = self.mi
        total = 0
        for n in split_passes(int(camera.width), int(camera.height), spp, self.max_lanes):
            total += sampler_count(mi, self.inputs.sampler, n)
        return total

    def render_forward(
        self, camera: PathCamera | None = None, *, spp: int | None = None, seed: int | None = None
    ) -> np.ndarray:
        """Forward-mode derivative of the image, (H, W, 3), along the tangents set on ``params``.

        Set them first: ``dr.enable_grad(p)`` and ``dr.set_grad(p, tangent)`` on
        entries of :attr:`params`.  Path replay (see :mod:`.integrator`): a primal
        pass gives each path's radiance, a second pass over the same paths
        accumulates ``dr.forward_to`` of each vertex's differentiable terms.
        """
        import drjit as dr

        self.activate()
        mi = self.mi
        camera = camera or self.inputs.camera
        spp = int(self.inputs.spp if spp is None else spp)
        seed = int(self.inputs.seed if seed is None else seed)
        w, h = int(camera.width), int(camera.height)
        kernel = self.kernel()
        # Push the tangents into the textures built from the parameters (the loops below
        # differentiate in isolation and must find them there already).
        attached = [v for v in self.params.values() if dr.grad_enabled(v)]
        if attached:
            dr.enqueue(dr.ADMode.Forward, *attached)
            dr.traverse(dr.ADMode.Forward, dr.ADFlag.ClearEdges)
        acc = np.zeros((h * w, 3), np.float64)
        total = 0
        with dr.suspend_grad():
            for _, sampler, ray, used in self._passes(camera, spp, seed):
                L, _, _ = kernel.sample(dr.ADMode.Primal, sampler.clone(), ray, None, None, mi.Bool(True))
                dr.eval(L)
                δL, _, _ = kernel.sample(dr.ADMode.Forward, sampler, ray, None, L, mi.Bool(True))
                dr.eval(δL)
                out = np.stack([np.asarray(δL.x), np.asarray(δL.y), np.asarray(δL.z)], axis=1).astype(np.float64)
                acc += out.reshape(h * w, used, 3).sum(axis=1)
                total += used
        return (acc / total).reshape(h, w, 3).astype(np.float32)

    def render_backward(
        self, grad_image: Any, camera: PathCamera | None = None, *, spp: int | None = None, seed: int | None = None
    ) -> None:
        """Reverse mode: accumulate ∂(Σ grad_image · image)/∂p into ``dr.grad(p)`` of every ``params`` entry with
        gradients enabled.  ``grad_image``: (H, W, 3) array or ``TensorXf``, the adjoint of the image."""
        import drjit as dr

        self.activate()
        mi = self.mi
        camera = camera or self.inputs.camera
        spp = int(self.inputs.spp if spp is None else spp)
        seed = int(self.inputs.seed if seed is None else seed)
        w, h = int(camera.width), int(camera.height)
        g = np.asarray(grad_image, dtype=np.float32).reshape(h * w, 3)
        total = self._spp_total(camera, spp)
        kernel = self.kernel()
        with dr.suspend_grad():
            for _, sampler, ray, used in self._passes(camera, spp, seed):
                # Each path's share of its pixel's adjoint: the image is the mean of all its paths.
                lanes = np.repeat(g / total, used, axis=0)
                δL = mi.Color3f(*[mi.Float(mappable(lanes[:, c])) for c in range(3)])
                L, _, _ = kernel.sample(dr.ADMode.Primal, sampler.clone(), ray, None, None, mi.Bool(True))
                dr.eval(L)
                kernel.sample(dr.ADMode.Backward, sampler, ray, δL, L, mi.Bool(True))
                dr.eval()  # run the kernel whose side effects are the parameter gradients

    def render_ad(self, camera: PathCamera | None = None, *, spp: int | None = None, seed: int | None = None) -> Any:
        """The image as a ``TensorXf`` (H, W, 3) attached to the AD graph of :attr:`params`.

        Use it like ``mi.render``: build a loss from it and call ``dr.backward``
        (reverse mode, through :meth:`render_backward`) or ``dr.forward``
        (through :meth:`render_forward`); only the parameters with gradients
        enabled are differentiated.
        """
        import drjit as dr

        self.activate()
        attached = {k: v for k, v in self.params.items() if dr.grad_enabled(v)}
        op: Any = _render_op()
        return dr.custom(op, self, camera or self.inputs.camera, spp, seed, attached)

    def layers(self, camera: PathCamera | None = None) -> dict[str, np.ndarray]:
        """Per pixel, from one ray through its centre: ``depth`` (metres from the camera to the first opaque
        hit; the far clip where nothing is hit), ``id`` (InstanceSet id, −1 none), ``species`` (index, −1 none),
        ``position`` (H, W, 3: the hit's world position, 0 where none) and ``row`` (the hit's row: a tree
        index < N, N for world-space parts — terrain, merged far trees — and −1 where nothing is hit).

        A cut-out texel counts as opaque where α ≥ 0.5, up to the tracer's skip limit.
        """
        import drjit as dr

        mi = self.mi
        camera = camera or self.inputs.camera
        w, h = int(camera.width), int(camera.height)
        kernel = self.kernel()
        with dr.suspend_grad():
            idx = dr.arange(mi.UInt32, w * h)
            pos = mi.Point2f((mi.Float(idx % w) + 0.5) / w, (mi.Float(idx // w) + 0.5) / h)
            ray, _ = self.sensor(camera).sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
            valid, _, row, p, *_ = kernel.trace(ray.o, ray.d, ray.maxt, None, mi_bool(mi, True), threshold=LAYER_ALPHA)
            origin = np.asarray(camera.to_world, np.float64)[:3, 3]
            dist = dr.norm(p - mi.Point3f(*[float(v) for v in origin]))
            dr.eval(valid, row, dist, p)
            valid_np = np.asarray(valid).astype(bool)
            position = np.stack([np.asarray(c, np.float64) for c in (p.x, p.y, p.z)], axis=1)
            depth = np.where(valid_np, np.asarray(dist, np.float64), float(camera.far))
            rows = np.asarray(row, np.int64)
        n = self.geometry.n_trees
        tree = valid_np & (rows < n)
        inst = self.inputs.instances
        ids = np.full(w * h, -1.0)
        species = np.full(w * h, -1.0)
        ids[tree] = inst.id[rows[tree]].astype(np.float64)
        species[tree] = np.asarray(inst.species)[rows[tree]].astype(np.float64)
        shape = (h, w)
        position[~valid_np] = 0.0
        return {
            "depth": depth.reshape(shape).astype(np.float32),
            "id": ids.reshape(shape).astype(np.float32),
            "species": species.reshape(shape).astype(np.float32),
            "position": position.reshape(h, w, 3).astype(np.float32),
            "row": np.where(valid_np, rows, -1).reshape(shape),
        }


_RENDER_OP: list[type] = []


def _render_op() -> type:
    """The drjit ``CustomOp`` behind :meth:`PathScene.render_ad` (defined on first use: drjit loads lazily)."""
    if _RENDER_OP:
        return _RENDER_OP[0]
    import drjit as dr

    class RenderOp(dr.CustomOp):
        """Primal: :meth:`PathScene.render`; derivatives: :meth:`PathScene.render_forward` / ``render_backward``."""

        # params (the attached parameters) is passed through dr.custom only so drjit tracks its gradients
        def eval(
            self,
            scene: PathScene,
            camera: PathCamera,
            spp: int | None,
            seed: int | None,
            params: dict[str, Any],  # noqa: ARG002
        ) -> Any:
            self.scene, self.camera, self.spp, self.seed = scene, camera, spp, seed
            mi = scene.mi
            img = scene.render(camera, spp=spp, seed=seed).rgb
            return mi.TensorXf(mappable(np.asarray(img, dtype=np.float32)))

        def forward(self) -> None:
            mi = self.scene.mi
            d = self.scene.render_forward(self.camera, spp=self.spp, seed=self.seed)
            self.set_grad_out(mi.TensorXf(mappable(np.asarray(d, dtype=np.float32))))

        def backward(self) -> None:
            g = np.asarray(self.grad_out(), dtype=np.float32)
            self.scene.render_backward(g, self.camera, spp=self.spp, seed=self.seed)

        def name(self) -> str:
            return "forest_path render"

    _RENDER_OP.append(RenderOp)
    return RenderOp


def mi_bool(mi: Any, value: bool) -> Any:
    """A Mitsuba ``Bool`` holding ``value`` (the all-lanes mask)."""
    return mi.Bool(value)


def mi_float(mi: Any, mask: Any) -> Any:
    """``mask`` as a Float: 1 where set, 0 elsewhere."""
    import drjit as dr

    return dr.select(mask, mi.Float(1.0), mi.Float(0.0))


def render_frame(inputs: PathInputs, variant: str = "llvm_ad_rgb") -> dict[str, Any]:
    """Render one frame of ``inputs``: ``rgb`` (H, W, 3), ``alpha`` (coverage), ``depth``, ``id``, ``species``.

    A convenience over :class:`PathScene` for a single still; keep the
    ``PathScene`` to render more passes, cameras or poses of the same forest.
    """
    scene = PathScene(inputs, variant)
    img = scene.render()
    out: dict[str, Any] = {"rgb": img.rgb, "alpha": img.alpha, "spp": img.spp}
    out.update(scene.layers())
    out["stats"] = scene.stats
    out["render_seconds"] = img.seconds
    out["load_seconds"] = scene.load_seconds
    return out
