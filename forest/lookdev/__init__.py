"""Look-dev: fit a forest's colour map and lights to a reference photo by differentiable rendering.

``match(config, reference, out_dir)`` is what ``forest match`` and the job
service call.  The pipeline:

1. the reference is read, checked, cropped to the camera's aspect and
   resampled to the optimiser's resolution (:mod:`.reference`);
2. the forest is scattered (or its saved InstanceSet read) and baked into a
   differentiable proxy — low-LOD trees merged into one mesh per material —
   loaded in ``llvm_ad_rgb`` or ``cuda_ad_rgb`` (:mod:`.forest_proxy`); with
   ``calibrate`` (the default in ``statistics`` mode) a small production
   render of the starting look sets a per-channel gain on the proxy
   (:mod:`.calibrate`);
3. Adam fits the colour grid, the sun and the sky through Mitsuba's ``prb``
   integrator against an ``aligned`` pixel loss or a ``statistics`` loss
   (sliced Wasserstein in Oklab), an aligned fit finishing with Gauss–Newton
   steps and iterate averaging (:mod:`.losses`, :mod:`.optimise`), with the
   parametrisation of :mod:`.state` that makes the fit identifiable;
4. the result is written: ``scene.toml`` (the same scene with the fitted map
   beside it and the light values in), ``colour_map.exr``, ``report.png``
   and ``match.json`` (:mod:`.report`), all atomically.

Settings come from the call, else from the config's ``[lookdev]`` table, else
the defaults below.
"""

from __future__ import annotations

import time
import warnings as _warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..atomic import atomic_dir
from ..config import Config, load_config
from ..errors import ForestError, ParameterError
from .state import DEFAULT_PARAMS, PARAM_GROUPS, LookState, state_from_config

MODES = ("aligned", "statistics")
DEFAULTS = {
    "iterations": 200,
    "resolution": 96,
    "spp": 8,
    "mode": "aligned",
    "grid": 16,
    "bands": 2,
    "fit": "crop",
    "max_triangles": 2_000_000,
    "max_depth": None,
    "lod": "high",
}
LOOKDEV_KEYS = (
    "iterations",
    "resolution",
    "spp",
    "params",
    "mode",
    "grid",
    "bands",
    "mask",
    "fit",
    "max_triangles",
    "max_depth",
    "variant",
    "lod",
    "calibrate",
)
EVAL_SPP = 64
SEED_TAG = 0x100CDE7


@dataclass
class MatchResult:
    """What ``match`` wrote and what it found."""

    out_dir: Path
    scene_path: Path
    colour_map_path: Path | None
    report_path: Path
    json_path: Path
    start: LookState
    result: LookState
    fitted: tuple[str, ...]
    losses: list[float]
    figures: dict
    variant: str
    seconds: float
    warnings: list[str] = field(default_factory=list)

    @property
    def paths(self) -> list[Path]:
        return [p for p in (self.scene_path, self.colour_map_path, self.report_path, self.json_path) if p]


@dataclass
class Settings:
    iterations: int
    resolution: int
    spp: int
    params: tuple[str, ...]
    mode: str
    grid: int
    bands: int
    fit: str
    max_triangles: int
    max_depth: int
    lod: str
    mask: Path | None
    variant: str
    calibrate: bool = False


def parse_params(value, param: str = "params") -> tuple[str, ...]:
    """``"colour_map,sun,sky"`` or a list → validated tuple of parameter groups (errors name ``param``)."""
    items = value.split(",") if isinstance(value, str) else list(value)
    out = []
    for it in items:
        it = str(it).strip()
        if not it:
            continue
        if it not in PARAM_GROUPS:
            raise ParameterError(param, f"unknown parameter {it!r} (expected some of {', '.join(PARAM_GROUPS)})")
        if it not in out:
            out.append(it)
    if not out:
        raise ParameterError(param, f"give at least one of {', '.join(PARAM_GROUPS)}")
    return tuple(out)


def resolve_settings(
    config: Config,
    *,
    iterations=None,
    resolution=None,
    spp=None,
    params=None,
    mode=None,
    mask=None,
    variant=None,
    grid=None,
) -> Settings:
    """Call arguments over ``[lookdev]`` over defaults, each validated with the field it came from."""
    f = config.section("lookdev", LOOKDEV_KEYS)

    def pick(value, key, lo, hi):
        if value is None:
            return f.integer(key, DEFAULTS[key], lo=lo, hi=hi)
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise ParameterError(key, f"must be a whole number from {lo} to {hi}, got {value!r}")
        return int(value)

    s_iter = pick(iterations, "iterations", 1, 100_000)
    s_res = pick(resolution, "resolution", 8, 4096)
    s_spp = pick(spp, "spp", 1, 4096)
    s_grid = pick(grid, "grid", 1, 64)
    if params is None:
        raw = f.table.get("params", list(DEFAULT_PARAMS))
        if not isinstance(raw, (list, str)):
            f.fail("params", f"must be a list of names, got {raw!r}")
        try:
            s_params = parse_params(raw)
        except ParameterError as e:
            f.fail("params", e.message)
    else:
        s_params = parse_params(params)
    if mode is None:
        s_mode = f.string("mode", DEFAULTS["mode"], choices=MODES)
    elif mode not in MODES:
        raise ParameterError("mode", f"must be one of {', '.join(MODES)}, got {mode!r}")
    else:
        s_mode = mode
    s_mask = Path(mask) if mask is not None else f.file("mask")
    if variant is None:
        variant = f.string("variant", None, choices=("llvm_ad_rgb", "cuda_ad_rgb"))
    if variant is None:
        from ..runtime import cuda_available

        variant = "cuda_ad_rgb" if cuda_available() else "llvm_ad_rgb"
    if variant not in ("llvm_ad_rgb", "cuda_ad_rgb"):
        raise ParameterError(
            "variant", f"look-dev needs a differentiable variant (llvm_ad_rgb or cuda_ad_rgb), got {variant!r}"
        )
    return Settings(
        iterations=s_iter,
        resolution=s_res,
        spp=s_spp,
        params=s_params,
        mode=s_mode,
        grid=s_grid,
        bands=f.integer("bands", DEFAULTS["bands"], lo=1, hi=16),
        fit=f.string("fit", DEFAULTS["fit"], choices=("crop", "stretch")),
        max_triangles=f.integer("max_triangles", DEFAULTS["max_triangles"], lo=1000, hi=100_000_000),
        max_depth=f.integer("max_depth", config.render.max_depth, lo=1, hi=64),
        lod=f.string("lod", DEFAULTS["lod"], choices=("high", "medium", "low", "far")),
        mask=s_mask,
        variant=variant,
        calibrate=f.boolean("calibrate", s_mode == "statistics"),
    )


def optimiser_size(config: Config, resolution: int) -> tuple[int, int]:
    """(width, height) with the long side ``resolution`` and the render's aspect ratio."""
    w, h = config.render.width, config.render.height
    if w >= h:
        return resolution, max(1, round(resolution * h / w))
    return max(1, round(resolution * w / h)), resolution


def start_grid(config: Config, n: int) -> np.ndarray:
    """The current colour map resampled to n×n cells (area average), or white (no map = untinted)."""
    if config.maps.colour is None:
        return np.ones((n, n, 3))
    from ..images import read_map_rgb, resample

    m = read_map_rgb(config.maps.colour, what="colour map")
    return np.clip(resample(m, n, n).astype(np.float64), 0.0, 1.0)


def colour_errors(image: np.ndarray, reference, mode: str, bands: int) -> tuple[float, float]:
    """(mean, 95th percentile) CIEDE2000 between an image and the reference.

    ``aligned``: per pixel, over pixels the mask keeps (weight ≥ ½).
    ``statistics``: between the mean colours of corresponding cells of a
    ``bands × bands`` grid of image regions (pixels do not correspond).
    """
    from .colour import delta_e2000

    w = reference.weight >= 0.5
    if mode == "aligned":
        de = delta_e2000(image[w], reference.rgb[w])
    else:
        h, wd = reference.shape
        de = []
        for i in range(bands):
            for j in range(bands):
                ys, xs = slice(i * h // bands, (i + 1) * h // bands), slice(j * wd // bands, (j + 1) * wd // bands)
                sel = w[ys, xs]
                if not sel.any():
                    continue
                de.append(float(delta_e2000(image[ys, xs].reshape(-1, 3).mean(0), reference.rgb[ys, xs][sel].mean(0))))
        de = np.asarray(de)
    return float(np.mean(de)), float(np.percentile(de, 95))


def match(
    config,
    reference,
    out_dir,
    *,
    iterations: int | None = None,
    resolution: int | None = None,
    spp: int | None = None,
    params=None,
    mode: str | None = None,
    mask=None,
    variant: str | None = None,
    progress=None,
    grid: int | None = None,
    instances=None,
    library=None,
    seed: int | None = None,
    start: LookState | None = None,
) -> MatchResult:
    """Fit the colour map and lights of ``config``'s scene to ``reference``; write the results to ``out_dir``.

    ``config``: a :class:`~forest.config.Config` or a path; ``reference``: an
    image path (or an (H, W, 3) linear array); ``progress(fraction, message)``
    receives the current loss.  ``instances`` (an InstanceSet or a saved one's
    path) skips the scatter; ``start`` overrides the starting look.
    """
    t0 = time.perf_counter()
    report = progress or (lambda f, m="": None)
    if not isinstance(config, Config):
        config = load_config(config)
    config.validate_all()
    st = resolve_settings(
        config,
        iterations=iterations,
        resolution=resolution,
        spp=spp,
        params=params,
        mode=mode,
        mask=mask,
        variant=variant,
        grid=grid,
    )
    from ..runtime import mitsuba

    mitsuba(st.variant)
    from .forest_proxy import build_proxy
    from .losses import make_loss
    from .optimise import optimise
    from .reference import load_reference
    from .report import MAP_NAME, scene_data, write_json, write_map, write_report, write_scene

    width, height = optimiser_size(config, st.resolution)
    notes: list[str] = []
    with _warnings.catch_warnings(record=True) as caught:
        _warnings.simplefilter("always")
        ref = load_reference(reference, width, height, mask=st.mask, fit=st.fit)
    notes += [str(w.message) for w in caught]
    report(0.0, "scattering")
    from ..terrain import load_terrain

    terrain = load_terrain(config.terrain, config.path)
    if instances is None or isinstance(instances, (str, Path)):
        from ..scatter import scene_instances

        instances = scene_instances(config, instances)
    base = start_grid(config, st.grid)
    start_state = start.copy() if start is not None else state_from_config(config, base)
    if start is not None and start.grid.shape[:2] != (st.grid, st.grid):
        raise ForestError(f"start grid is {start.grid.shape[0]}x{start.grid.shape[1]}, expected {st.grid}x{st.grid}")
    report(0.02, "building the proxy")
    proxy = build_proxy(
        config,
        instances,
        terrain,
        width=width,
        height=height,
        grid_shape=(st.grid, st.grid),
        variant=st.variant,
        library=library,
        state=start_state,
        max_triangles=st.max_triangles,
        max_depth=st.max_depth,
        lod=st.lod,
    )
    rseed = int(config.seed if seed is None else seed)
    loss = make_loss(st.mode, ref, seed=rseed, bands=st.bands)
    gain = None
    if st.calibrate and len(instances):
        from .calibrate import channel_gain, production_image

        report(0.03, "calibrating the proxy against the production render")
        production = production_image(config, instances, start_state, width=width, height=height, library=library)
        proxy.set_state(start_state)
        gain = channel_gain(production, proxy.render_numpy(EVAL_SPP, rseed + 13), ~proxy.sky_mask())
        proxy.set_gain(gain)
    fit = optimise(
        proxy,
        loss,
        start_state,
        groups=st.params,
        mode=st.mode,
        iterations=st.iterations,
        spp=st.spp,
        seed=rseed,
        base_grid=base,
        progress=lambda f, m: report(0.05 + 0.85 * f, m),
    )
    notes += fit.warnings
    report(0.92, "evaluating")
    proxy.set_state(fit.start)
    img_start = proxy.render_numpy(EVAL_SPP, rseed + 11, passes=2)
    proxy.set_state(fit.result)
    img_result = proxy.render_numpy(EVAL_SPP, rseed + 11, passes=2)
    s_mean, s_p95 = colour_errors(img_start, ref, st.mode, st.bands)
    r_mean, r_p95 = colour_errors(img_result, ref, st.mode, st.bands)
    figures = {
        "start_delta_e_mean": s_mean,
        "start_delta_e_p95": s_p95,
        "result_delta_e_mean": r_mean,
        "result_delta_e_p95": r_p95,
        "start_loss": float(loss.numpy(img_start)),
        "result_loss": float(loss.numpy(img_result)),
    }
    out_dir = Path(out_dir)
    result_state = fit.result
    with atomic_dir(out_dir) as tmp:
        if "colour_map" in fit.fitted:
            write_map(tmp / MAP_NAME, result_state.grid)
        data = scene_data(config, result_state, fit.fitted, out_dir)
        write_scene(tmp / "scene.toml", data)
        write_report(
            tmp / "report.png",
            reference=ref.rgb,
            start=img_start,
            result=img_result,
            losses=fit.losses,
            trajectories=fit.trajectories,
            figures=figures,
            title=f"forest match — {st.mode}, {st.iterations} iterations × {st.spp} spp at {width}×{height}, "
            f"fitted: {', '.join(fit.fitted)}",
        )
        write_json(
            tmp / "match.json",
            {
                "mode": st.mode,
                "iterations": st.iterations,
                "spp": st.spp,
                "resolution": [width, height],
                "grid": st.grid,
                "fitted": list(fit.fitted),
                "figures": {k: float(f"{v:.6g}") for k, v in figures.items()},
                "start": {k: round(v, 6) for k, v in fit.start.light_values().items()},
                "result": {k: round(v, 6) for k, v in result_state.light_values().items()},
                "proxy": proxy.stats,
                "warnings": notes,
                "calibration_gain": None if gain is None else [round(float(x), 5) for x in gain],
                "loss": [float(f"{x:.6g}") for x in fit.losses],
                "sun_search": [[round(a, 4), round(b, 4), float(f"{c:.6g}")] for a, b, c in fit.search],
            },
        )
    report(1.0, f"ΔE00 {r_mean:.2f}")
    return MatchResult(
        out_dir=out_dir,
        scene_path=out_dir / "scene.toml",
        colour_map_path=(out_dir / MAP_NAME) if "colour_map" in fit.fitted else None,
        report_path=out_dir / "report.png",
        json_path=out_dir / "match.json",
        start=fit.start,
        result=result_state,
        fitted=fit.fitted,
        losses=fit.losses,
        figures=figures,
        variant=st.variant,
        seconds=time.perf_counter() - t0,
        warnings=notes,
    )


__all__ = ["LookState", "MatchResult", "match", "parse_params", "resolve_settings"]
