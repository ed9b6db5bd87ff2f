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
from ..config import Config, ConfigError
from ..errors import ForestError, ParameterError
from .state import DEFAULT_PARAMS, PARAM_GROUPS, LookState, state_from_config

MODES = ("aligned", "statistics")
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


def parse_params(value, where: str = "lookdev.params") -> tuple[str, ...]:
    """``"colour_map,sun,sky"`` or a list → validated tuple of parameter groups."""
    items = value.split(",") if isinstance(value, str) else list(value)
    out = []
    for it in items:
        it = str(it).strip()
        if not it:
            continue
        if it not in PARAM_GROUPS:
            raise ParameterError(where, f"unknown parameter {it!r} (expected some of {', '.join(PARAM_GROUPS)})")
        if it not in out:
            out.append(it)
    if not out:
        raise ParameterError(where, f"give at least one of {', '.join(PARAM_GROUPS)}")
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
    """Call arguments over ``[lookdev]`` over its defaults.

    The call's arguments are applied as overrides of ``lookdev.<name>`` and
    validated by the scene schema, so a bad argument is reported with the
    parameter's name (``lookdev.iterations: must be <= 100000, got 0``).
    """
    given = {
        "iterations": iterations,
        "resolution": resolution,
        "spp": spp,
        "mode": mode,
        "grid": grid,
        "variant": variant,
    }
    if params is not None:
        given["params"] = (
            [p.strip() for p in params.split(",") if p.strip()] if isinstance(params, str) else list(params)
        )
    overrides = {f"lookdev.{k}": v for k, v in given.items() if v is not None}
    if mask is not None:
        overrides["lookdev.mask"] = str(Path(mask).resolve())
    if overrides:
        try:
            config = config.with_overrides(overrides)
        except ConfigError as e:
            if e.field in overrides:
                raise e.for_parameter(e.field) from None
            raise
    lk = config.lookdev
    s_params = parse_params(lk.params if lk.params is not None else list(DEFAULT_PARAMS), "lookdev.params")
    variant = lk.variant
    if variant is None:
        from ..runtime import cuda_available

        variant = "cuda_ad_rgb" if cuda_available() else "llvm_ad_rgb"
    return Settings(
        iterations=lk.iterations,
        resolution=lk.resolution,
        spp=lk.spp,
        params=s_params,
        mode=lk.mode,
        grid=lk.grid,
        bands=lk.bands,
        fit=lk.fit,
        max_triangles=lk.max_triangles,
        max_depth=lk.max_depth if lk.max_depth is not None else config.render.max_depth,
        lod=lk.lod,
        mask=lk.mask,
        variant=variant,
        calibrate=lk.calibrate if lk.calibrate is not None else lk.mode == "statistics",
    )


def optimiser_size(config: Config, resolution: int) -> tuple[int, int]:
    """(width, height) with the long side ``resolution`` and the render's aspect ratio."""
    w, h = config.render.width, config.render.height
    if w >= h:
        return resolution, max(1, round(resolution * h / w))
    return max(1, round(resolution * w / h)), resolution


def start_grid(scene, n: int) -> np.ndarray:
    """The scene's colour map resampled to n×n cells (area average), or white (no map = untinted)."""
    if scene.colour is None:
        return np.ones((n, n, 3))
    from ..images import resample

    return np.clip(resample(scene.colour.rgb, n, n).astype(np.float64), 0.0, 1.0)


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
    scene,
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
    seed: int | None = None,
    start: LookState | None = None,
) -> MatchResult:
    """Fit the colour map and lights of a :class:`~forest.scene.Scene` to ``reference``; write the results to ``out_dir``.

    ``reference``: an image path (or an (H, W, 3) linear array);
    ``progress(fraction, message)`` receives the current loss; ``start``
    overrides the starting look.
    """
    t0 = time.perf_counter()
    report = progress or (lambda f, m="": None)
    config, instances = scene.config, scene.instances
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
    base = start_grid(scene, st.grid)
    start_state = start.copy() if start is not None else state_from_config(config, base)
    if start is not None and start.grid.shape[:2] != (st.grid, st.grid):
        raise ForestError(f"start grid is {start.grid.shape[0]}x{start.grid.shape[1]}, expected {st.grid}x{st.grid}")
    report(0.02, "building the proxy")
    proxy = build_proxy(
        scene,
        width=width,
        height=height,
        grid_shape=(st.grid, st.grid),
        variant=st.variant,
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
        production = production_image(scene, start_state, width=width, height=height)
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
