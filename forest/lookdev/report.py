"""What a fit writes, and the report an artist reads.

* ``scene.toml`` — the input scene with every fitted value in it.  The camera's
  exposure and white balance are folded into the lights (sun, sky, haze
  radiance × 2^EV·W): the path tracer is linear in its lights and renders each
  channel on its own, so ``forest render scene.toml`` gives the photo the fit
  modelled.  A tilted sky is written as ``sky.exr`` (a latitude–longitude map
  of the gradient, +Y up, 512×256) and ``[lights.sky] envmap``; an untilted
  one as a constant sky.  The ground's multiplier goes to ``[lookdev] ground_tint``
  (whatever makes the ground's albedo: one colour, a map or the ``[ground]`` rules),
  leaf colours to ``[lookdev] leaf_tint`` by species, haze to ``[render] haze``
  and ``haze_colour``, the colour map (the tint it is, ``colour_normalise = "none"``)
  to ``colour_map.exr`` at the painted map's resolution.  Paths are rebased so the file renders from where it lies.
* ``report.png`` — the reference, and **production renders** (of the start
  config and of the written ``scene.toml``) at ``[lookdev] report_width``; the
  colour map before and after; each region's mean colour (photo, start,
  fitted) with its CIEDE2000; the held-out objective per iteration, with the
  start and the kept iterate marked; the table of every parameter with its
  range, prior, how much the reference determined it, and its flags.
* ``match.json`` — all of it as numbers.

Values are rounded (6 significant digits, the map to 1/65536) so files do not
depend on the last bits of a sum.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from ..atomic import atomic_dir, atomic_path
from ..config import load_config, rebase_paths
from ..images import linear_to_srgb, write_image
from ..render.path.emitters import gradient_radiance
from .colour import luminance
from .fit import determination
from .look import camera_gain, ground_tint, haze_colour, leaf_tints, lights

if TYPE_CHECKING:
    from ..config import Config
    from ..scene import Scene
    from .fit import FitResult, Fitter
    from .match import Settings
    from .params import Look
    from .reference import Reference
    from .renders import FitRenderer
    from .solve import Problem

#: (region, photo, start and fitted mean colours, ΔE00 of start and of fitted) per region (:func:`_region_means`).
RegionMeans = list[tuple[str, np.ndarray, np.ndarray, np.ndarray, float, float]]

MAP_NAME = "colour_map.exr"
SKY_NAME = "sky.exr"
#: Every file ``forest match`` may write into its output folder (none of them may be one of its inputs).
WRITTEN = ("scene.toml", MAP_NAME, SKY_NAME, "report.png", "match.json")
SKY_SIZE = (256, 512)
#: A gradient whose zenith and horizon differ by less than this (relative, per channel) is written as constant.
FLAT_SKY = 0.01


def _r(x: float, digits: int = 6) -> float:
    return float(f"{float(x):.{digits}g}")


def _rgb(v: npt.ArrayLike) -> list[float]:
    return [_r(c) for c in np.asarray(v, np.float64).ravel()[:3]]


def gradient_envmap(
    zenith: np.ndarray, horizon: np.ndarray, size: tuple[int, int] = SKY_SIZE, exponent: float = 1.0
) -> np.ndarray:
    """The gradient sky L = zenith·(1 − b) + horizon·b, b = (1 − μ)^k, μ = max(ω_y, 0)
    (:func:`forest.render.path.emitters.gradient_radiance`), as a latitude–longitude map (+Y up,
    Mitsuba's ``envmap`` convention: row i at polar angle π(i + ½)/H)."""
    h, w = size
    mu = np.maximum(np.cos(np.pi * (np.arange(h) + 0.5) / h), 0.0)[:, None, None]
    img = gradient_radiance(zenith, horizon, mu, exponent)
    return np.broadcast_to(img, (h, w, 3)).astype(np.float32)


def fitted_data(
    config: Config, problem: Problem, look: Look, out_dir: Path, *, fit_map: bool
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """(TOML-ready config dict, files to write beside it) for a fitted look (see the module docstring)."""
    start = problem.start
    data = rebase_paths(config.data, Path(config.base_dir), Path(out_dir))
    files: dict[str, np.ndarray] = {}
    g = camera_gain(look)
    lt = lights(look, start)
    lights_d = data.setdefault("lights", {})
    if lt.sun is not None:
        e = g * lt.sun
        y = float(luminance(e))
        sun = lights_d.setdefault("sun", {})
        sun["irradiance"] = _r(y)
        sun["colour"] = _rgb(e / y if y > 0 else np.ones(3))
    sky = lights_d.setdefault("sky", {})
    if lt.zenith is not None:
        z, hz = g * lt.zenith, g * lt.horizon
        if np.all(np.abs(z - hz) <= FLAT_SKY * np.maximum(np.abs(z), 1e-9)):
            y = float(luminance(z))
            sky.clear()
            sky["radiance"] = _r(y)
            sky["colour"] = _rgb(z / y if y > 0 else np.ones(3))
        else:
            sky.clear()
            sky["envmap"] = SKY_NAME
            files[SKY_NAME] = gradient_envmap(z, hz, exponent=start.sky_exponent)
    elif start.sky_kind == "envmap" and lt.sky_scale is not None:
        from ..images import read_image

        sky_cfg = config.lights.sky
        assert sky_cfg is not None and sky_cfg.envmap is not None  # the start's sky kind is the config's
        src = read_image(sky_cfg.envmap, what="environment map")[..., :3]
        sky["envmap"] = SKY_NAME
        sky.pop("scale", None)
        files[SKY_NAME] = (src * (float(lt.sky_scale[0]) * float(sky_cfg.scale)) * g).astype(np.float32)
    elif start.sky_kind == "sunsky" and lt.sky_scale is not None:
        sky_cfg = config.lights.sky
        assert sky_cfg is not None and sky_cfg.sunsky is not None  # the start's sky kind is the config's
        sky.setdefault("sunsky", {})["scale"] = _r(float(sky_cfg.sunsky.scale) * float(np.mean(g)))
    rd = data.setdefault("render", {})
    sigma = look.get("haze", start.haze)
    if start.has_haze and (sigma > 0 or config.render.haze > 0):
        rd.pop("visibility", None)  # the fitted haze replaces a visibility (the two are exclusive)
        rd["haze"] = _r(sigma)
        rd["haze_colour"] = _rgb(g * haze_colour(start, lt))
    gt = ground_tint(look)
    if not np.allclose(gt, 1.0, atol=1e-6):
        data.setdefault("lookdev", {})["ground_tint"] = _rgb(start.ground_tint0 * gt)
    tints = leaf_tints(look, problem.n_species)
    if not np.allclose(tints, 1.0, atol=1e-6):
        old = data.get("lookdev", {}).get("leaf_tint", {}) or {}
        table = dict(old)
        for s, label in enumerate(start.species):
            prev = np.asarray(old.get(label, (1.0, 1.0, 1.0)), np.float64)
            table[label] = _rgb(prev * tints[s])
        data.setdefault("lookdev", {})["leaf_tint"] = table
    if fit_map:
        maps = data.setdefault("maps", {})
        maps["colour"] = MAP_NAME
        maps["colour_normalise"] = "none"  # the fitted tint as it is: its mean is part of the fit
    return data, files


def rounded_grid(grid: np.ndarray) -> np.ndarray:
    """``grid`` clipped at 0 and rounded to 1/65536 as float32: the colour map as written, the same on every machine."""
    return (np.round(np.maximum(grid, 0.0) * 65536.0) / 65536.0).astype(np.float32)


HEADER = "# look-dev result: the scene's look fitted to a reference (forest match)"


def _plain(value: Any) -> Any:
    """A tomlkit item as plain Python (plain values pass through)."""
    unwrap = getattr(value, "unwrap", None)
    return unwrap() if callable(unwrap) else value


def sync_document(target: Any, data: dict[str, Any]) -> None:
    """Make the TOML container ``target`` (a tomlkit document or table) hold ``data``, editing in place.

    Keys whose values are unchanged keep their item, so their comments and
    formatting stay; changed values are replaced where they stand (a trailing
    comment stays); new keys are appended; keys ``data`` lacks are removed.
    Tables and same-length arrays of tables are walked into.
    """
    for key in [k for k in target if k not in data]:
        del target[key]
    for key, value in data.items():
        if key not in target:
            _append(target, key, value)
            continue
        old = target[key]
        if isinstance(value, dict) and isinstance(old, dict):
            sync_document(old, value)
        elif (
            isinstance(value, list)
            and isinstance(old, list)
            and len(old) == len(value)
            and value
            and all(isinstance(v, dict) and isinstance(o, dict) for v, o in zip(value, old, strict=True))
        ):
            for o, v in zip(old, value, strict=True):
                sync_document(o, v)
        elif not _same(_plain(old), value):
            target[key] = value


def _append(target: Any, key: str, value: Any) -> None:
    """Add ``key`` to ``target``; in a ``[table]``, before the comments and blank lines that end it (they
    introduce what follows, e.g. ``# --- lights ---`` above the next header)."""
    from tomlkit.items import Comment, Table, Whitespace

    if not isinstance(target, Table):
        target[key] = value
        return
    body = target.value.body
    tail = []
    while body and body[-1][0] is None and isinstance(body[-1][1], Comment | Whitespace):
        tail.append(body.pop())
    target[key] = value
    body.extend(reversed(tail))


def _same(a: Any, b: Any) -> bool:
    """Equal as TOML values (``1`` and ``1.0`` are, ``true`` and ``1`` are not)."""
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, bool) or isinstance(b, bool):
        return type(a) is type(b) and a == b
    return bool(a == b)


def fitted_document(data: dict[str, Any], original: str | None = None) -> str:
    """The text of the fitted ``scene.toml``: ``original`` (the artist's scene file, if given and readable)
    edited to hold ``data``, so its comments, key order and untouched values survive (:func:`sync_document`),
    under the look-dev header comment."""
    import tomlkit

    doc = None
    if original is not None:
        try:
            doc = tomlkit.parse(original.removeprefix("\ufeff"))
        except (tomlkit.exceptions.ParseError, RecursionError):  # unparsable now: write the values alone
            doc = None
    if doc is None:
        doc = tomlkit.document()
    sync_document(doc, data)
    text = tomlkit.dumps(doc)
    return text if text.startswith(HEADER) else HEADER + "\n" + text


def write_toml(path: Path, data: dict[str, Any], original: Path | str | None = None) -> Path:
    """Write the fitted scene ``data`` to ``path`` atomically as TOML (:func:`fitted_document`); ``original``
    is the scene file it was fitted from, whose comments and order the written file keeps. Returns ``path``."""
    text = None
    if original is not None:
        try:
            text = Path(original).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError):
            text = None
    out = fitted_document(data, text)
    with atomic_path(path) as tmp:
        tmp.write_text(out, encoding="utf-8")
    return path


class Production:
    """The production renderer of one Scene (the forest path tracer with its haze, as ``forest render`` builds it
    for the JIT variants), built once, rendered at any size."""

    def __init__(self, scene: Scene, variant: str):
        from ..render.path import PathScene
        from ..render.path.from_scene import path_inputs

        self.config = scene.config
        self.inputs = path_inputs(scene)
        self.scene = PathScene(self.inputs, variant)

    def image(self, *, width: int, height: int, spp: int, seed: int) -> np.ndarray:
        """Linear (H, W, 3) at ``width × height``."""
        from ..render.path.from_scene import with_size

        cam = with_size(self.inputs, width, height).camera
        return np.asarray(self.scene.render(cam, spp=spp, seed=seed).rgb, np.float64)


def production_image(scene: Scene, *, width: int, height: int, spp: int, seed: int, variant: str) -> np.ndarray:
    """The production render of a Scene at one size (see :class:`Production`)."""
    return Production(scene, variant).image(width=width, height=height, spp=spp, seed=seed)


def parameter_table(problem: Problem, result: FitResult) -> list[dict[str, Any]]:
    """One row per parameter: start and fitted value (raw and shown), range, prior, determination, flag."""
    rows = []
    for s in problem.specs:
        v0 = result.start.get(s.name, s.mean)
        v1 = result.best.get(s.name, v0)
        held = s.name in problem.held
        flag = ""
        if held:
            flag = "held: " + result.held.get(s.name, "")
        else:
            span = s.hi - s.lo
            if abs(v1 - v0) > 1e-9 and min(v1 - s.lo, s.hi - v1) <= 0.01 * span:
                flag = s.natural_lo if (s.natural_lo and v1 - s.lo <= s.hi - v1) else "on a bound"
            elif abs(v1 - s.mean) / s.sigma > 3.0:
                flag = f"{abs(v1 - s.mean) / s.sigma:.1f} σ from prior"
        rows.append(
            {
                "name": s.name,
                "label": s.label,
                "group": s.group,
                "start": _r(v0),
                "fitted": _r(v1),
                "start_shown": s.show(v0),
                "fitted_shown": s.show(v1),
                "range": s.show_range(),
                "lo": _r(s.lo),
                "hi": _r(s.hi),
                "prior": f"{s.show(s.mean)} ± {s.sigma:g}{' mired' if s.kind == 'mired' else ''}",
                "determined": _r(determination(result.shares.get(s.name, 1.0)), 3),
                "held": held,
                "flag": flag,
            }
        )
    return rows


def _region_figures(
    reference: Reference,
    photo_labels: np.ndarray,
    render_labels: np.ndarray,
    renderer: FitRenderer,
    image: np.ndarray,
) -> dict[str, float]:
    from .losses import RegionLoss
    from .regions import regions

    lay = renderer.layers
    regs = regions(
        render_labels, photo_labels, sky_up=lay["dir"][..., 1], sun_lit=None, render_img=image, photo_img=reference.rgb
    )
    return RegionLoss(reference.rgb, regs).delta_e(image)


def write_outputs(
    out_dir: Path,
    *,
    scene: Scene,
    settings: Settings,
    renderer: FitRenderer,
    problem: Problem,
    fitter: Fitter,
    result: FitResult,
    reference: Reference,
    photo_labels: np.ndarray,
    render_labels: np.ndarray,
    notes: list[str],
    seconds: float,
    seed: int,
    sun_lit: np.ndarray | None = None,
) -> dict[str, Any]:
    """Write everything into ``out_dir`` atomically; returns paths, the table and the figures (``sun_lit``:
    the render's sunlit pixels, for the lit-over-shadowed contrasts)."""
    from .colour import delta_e2000

    config = scene.config
    fit_map = problem.cells is not None
    best = result.best
    out: dict[str, Any] = {}
    w, h = renderer.width, renderer.height
    spp_eval = 4 * settings.spp
    with atomic_dir(out_dir) as tmp:
        data, files = fitted_data(config, problem, best, out_dir, fit_map=fit_map)
        for name, img in files.items():
            write_image(tmp / name, img, half=False)
        if fit_map:
            grid = fitter.grid(best)
            assert grid is not None  # a fitted map has a base map
            write_image(tmp / MAP_NAME, rounded_grid(grid), half=False)
            out["colour_map"] = out_dir / MAP_NAME
        # The temporary folder is the output folder's sibling: relative paths resolve the same from both.
        write_toml(tmp / "scene.toml", data, config.path)
        fitted_scene = scene.with_config(load_config(tmp / "scene.toml"))
        # Production renders of the start and of the written scene: figures at the fit's size, pictures larger.
        prod = {name: Production(sc, renderer.variant) for name, sc in (("start", scene), ("fitted", fitted_scene))}
        ev = {name: p.image(width=w, height=h, spp=spp_eval, seed=seed + 101) for name, p in prod.items()}
        clip: Callable[[np.ndarray], np.ndarray] = (
            (lambda x: np.minimum(x, 1.0)) if reference.display_referred else (lambda x: x)
        )
        figures: dict[str, Any] = {
            "objective_start": _r(sum(result.start_objective)),
            "objective_fitted": _r(sum(result.best_objective)),
            "data_start": _r(result.start_objective[0]),
            "data_fitted": _r(result.best_objective[0]),
            "best_iteration": result.best_iteration,
        }
        valid = (photo_labels >= 0).ravel()
        for name in ("start", "fitted"):
            img = clip(ev[name])
            de = delta_e2000(img.reshape(-1, 3)[valid], reference.rgb.reshape(-1, 3)[valid])
            figures[f"{name}_pixel_de_mean"] = _r(float(np.mean(de)), 4)
            figures[f"{name}_regions"] = {
                k: _r(v, 4) for k, v in _region_figures(reference, photo_labels, render_labels, renderer, img).items()
            }
        figures["region_statistics"] = _statistics(
            reference, photo_labels, render_labels, renderer, {k: clip(v) for k, v in ev.items()}, sun_lit
        )
        rw = int(settings.report_width)
        rh = max(1, round(rw * h / w))
        pics = {
            name: clip(p.image(width=rw, height=rh, spp=max(16, settings.spp), seed=seed + 202))
            for name, p in prod.items()
        }
        table = parameter_table(problem, result)
        labels = {r["name"]: r["label"] for r in table} | {f"map_mean_{c}": f"colour map mean {c}" for c in "rgb"}
        weak_text = [w.describe(labels) for w in result.weak]
        write_report(
            tmp / "report.png",
            reference=reference.rgb,
            start=pics["start"],
            fitted=pics["fitted"],
            table=table,
            figures=figures,
            history=result.history,
            maps=None if not fit_map else _leaf_maps(problem, fitter, result),
            settings=settings,
            size=(w, h),
            notes=[
                f"anchor ({ANCHOR_NOTE[problem.anchor]}): lookdev.anchor = {problem.anchor}",
                *(f"weak direction: {t}" for t in weak_text),
                *([] if weak_text else ["no weak direction: the reference determines every fitted parameter"]),
            ],
            region_means=_region_means(
                reference, photo_labels, render_labels, renderer, clip(ev["start"]), clip(ev["fitted"])
            ),
        )
        doc = {
            "mode": settings.mode,
            "groups": list(settings.params),
            "iterations": settings.iterations,
            "spp": settings.spp,
            "resolution": [w, h],
            "grid": problem.cells[0] if problem.cells is not None else None,
            "map_prior": settings.map_prior if fit_map else None,
            # What held the scale of albedos against light, and the directions the data left weak.
            "anchor": problem.anchor,
            "weak_directions": [
                {
                    "kind": w.kind,
                    "information": _r(w.information, 4),
                    "components": {k: _r(v, 3) for k, v in w.components.items()},
                }
                for w in result.weak
            ],
            "variant": renderer.variant,
            "figures": figures,
            "parameters": table,
            "held": result.held,
            # The gradient sky's shape: its horizon band exponent k (1: linear; see forest.lookdev.params).
            "sky_band_exponent": _r(problem.start.sky_exponent) if problem.start.sky_kind == "constant" else None,
            "history": [{k: (_r(v) if isinstance(v, float) else v) for k, v in e.items()} for e in result.history],
            "warnings": list(notes),
            "seconds": _r(seconds, 4),
        }
        with atomic_path(tmp / "match.json") as j:
            j.write_text(json.dumps(doc, indent=2, sort_keys=True, ensure_ascii=False) + "\n", encoding="utf-8")
    out.update(
        weak=weak_text,
        scene=out_dir / "scene.toml",
        report=out_dir / "report.png",
        json=out_dir / "match.json",
        table=table,
        figures=figures,
    )
    return out


def _statistics(
    reference: Reference,
    photo_labels: np.ndarray,
    render_labels: np.ndarray,
    renderer: FitRenderer,
    images: dict[str, np.ndarray],
    sun_lit: np.ndarray | None,
) -> dict[str, Any]:
    """Per region, beyond its mean: L*, a*, b* percentiles of the photo and of each image, and for canopy and
    ground the lit-over-shadowed luminance contrast (the render's sunlit share splits both alike)."""
    from .regions import CANOPY, GROUND, NAMES, lit_contrast, region_statistics, regions

    lay = renderer.layers
    regs = regions(
        render_labels,
        photo_labels,
        sky_up=lay["dir"][..., 1],
        sun_lit=None,
        render_img=images["fitted"],
        photo_img=reference.rgb,
    )
    out: dict[str, Any] = {}
    for r in regs:
        row = {"photo": region_statistics(reference.rgb, r.photo)}
        row.update({k: region_statistics(img, r.render) for k, img in images.items()})
        out[r.name] = {k: {c: [_r(x, 4) for x in v] for c, v in d.items()} for k, d in row.items()}
    if sun_lit is not None:
        for lab in (CANOPY, GROUND):
            rm, pm = (render_labels == lab).ravel(), (photo_labels == lab).ravel()
            if not rm.any() or not pm.any() or NAMES[lab] not in out:
                continue
            f = float(np.asarray(sun_lit).ravel()[rm].mean())
            if not 0.05 < f < 0.95:
                continue
            c = {"photo": lit_contrast(reference.rgb, pm, f)}
            c.update({k: lit_contrast(img, rm, f) for k, img in images.items()})
            out[NAMES[lab]]["lit_over_shadowed"] = {k: None if v is None else _r(v, 4) for k, v in c.items()}
    return out


#: What each anchor holds, for the report.
ANCHOR_NOTE = {
    "ground": "the ground keeps the scene's albedo, fixing albedos against light",
    "leaves": "the leaves keep the species' colours, fixing albedos against light",
    "lights": "the lights keep the scene's level, fixing albedos against light",
    "none": "nothing holds albedos against light but the priors",
}


def _leaf_maps(problem: Problem, fitter: Fitter, result: FitResult) -> tuple[np.ndarray, np.ndarray]:
    """The painted and the fitted colour map as the leaf colour they give (the species' mean leaf colour × the
    leaf tint × the map), so both show the canopy's albedo."""
    leaf = np.asarray(problem.start.leaf_colours, np.float64).mean(axis=0)
    t0 = leaf_tints(result.start, problem.n_species).mean(axis=0)
    t1 = leaf_tints(result.best, problem.n_species).mean(axis=0)
    return fitter.base_map * leaf * t0, fitter.grid(result.best) * leaf * t1


def _region_means(
    reference: Reference,
    photo_labels: np.ndarray,
    render_labels: np.ndarray,
    renderer: FitRenderer,
    start: np.ndarray,
    fitted: np.ndarray,
) -> RegionMeans:
    """(name, photo, start, fitted mean colours, ΔE start, ΔE fitted) per region."""
    from .colour import delta_e2000
    from .regions import regions

    lay = renderer.layers
    regs = regions(
        render_labels, photo_labels, sky_up=lay["dir"][..., 1], sun_lit=None, render_img=fitted, photo_img=reference.rgb
    )
    out = []
    for r in regs:
        p = reference.rgb.reshape(-1, 3)[r.photo].mean(0)
        s = start.reshape(-1, 3)[r.render].mean(0)
        f = fitted.reshape(-1, 3)[r.render].mean(0)
        out.append((r.name, p, s, f, float(delta_e2000(s, p)), float(delta_e2000(f, p))))
    return out


def _show(img: np.ndarray) -> np.ndarray:
    return linear_to_srgb(np.clip(img, 0.0, 1.0))


def write_report(
    path: Path,
    *,
    reference: np.ndarray,
    start: np.ndarray,
    fitted: np.ndarray,
    table: list[dict[str, Any]],
    figures: dict[str, Any],
    history: list[dict[str, Any]],
    maps: tuple[np.ndarray, np.ndarray] | None,
    settings: Settings,
    size: tuple[int, int],
    region_means: RegionMeans,
    notes: Sequence[str] = (),
) -> Path:
    """report.png (see the module docstring)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    rows = len(table) + 1
    table_height = 0.27 * rows
    notes_height = 0.3 + 0.18 * len(notes)  # inches below the table, in figure coordinates
    if maps is not None:
        heights = [3.2, 2.6, 3.0, table_height]
    else:
        heights = [3.2, 2.6, table_height]
    total = sum(heights) + 1.2 + notes_height
    fig = Figure(figsize=(15, total), dpi=90)
    fig.subplots_adjust(bottom=(notes_height + 0.3) / total)
    gs = fig.add_gridspec(len(heights), 3, height_ratios=heights, hspace=0.3, wspace=0.18)
    panels = (("reference", reference), ("start (production render)", start), ("fitted (production render)", fitted))
    for i, (name, img) in enumerate(panels):
        ax = fig.add_subplot(gs[0, i])
        ax.imshow(_show(img), interpolation="lanczos" if img.shape[1] < 400 else "nearest")
        if name.startswith("start"):
            name += f"\nΔE00 mean per pixel {figures['start_pixel_de_mean']:.2f}"
        elif name.startswith("fitted"):
            name += f"\nΔE00 mean per pixel {figures['fitted_pixel_de_mean']:.2f}"
        ax.set_title(name, fontsize=9)
        ax.axis("off")
    # Regions: photo / start / fitted swatches with ΔE.
    ax = fig.add_subplot(gs[1, 0:2])
    ax.set_title("mean colour per region: photo | start | fitted  (CIEDE2000 to the photo)", fontsize=9)
    n = max(len(region_means), 1)
    for i, (name, p, s, f, de_s, de_f) in enumerate(region_means):
        y = n - 1 - i
        for j, c in enumerate((p, s, f)):
            ax.add_patch(
                matplotlib.patches.Rectangle(
                    (j * 1.05, y + 0.1), 1.0, 0.8, color=np.clip(_show(np.asarray(c)[None])[0], 0, 1)
                )
            )
        line = f"{name}: ΔE {de_s:.1f} → {de_f:.1f}"
        st = figures.get("region_statistics", {}).get(name, {})
        if st.get("photo") and st.get("fitted"):
            p10, _, p90 = st["photo"]["L*"]
            f10, _, f90 = st["fitted"]["L*"]
            line += f"; L* 10–90 %: photo {p10:.0f}–{p90:.0f}, fitted {f10:.0f}–{f90:.0f}"
        c = st.get("lit_over_shadowed")
        if c and c.get("photo") and c.get("fitted"):
            line += f"; lit/shadowed {c['photo']:.2f} vs {c['fitted']:.2f}"
        ax.text(3.3, y + 0.5, line, va="center", fontsize=8)
    ax.set_xlim(0, 9.5)
    ax.set_ylim(0, n)
    ax.axis("off")
    # Objective per iteration.
    ax = fig.add_subplot(gs[1, 2])
    it = [e["iteration"] for e in history]
    tot = [e["total"] for e in history]
    dat = [e["data"] for e in history]
    ax.plot(it, tot, "o-", lw=1, ms=3, color="k", label="objective (held-out render)")
    ax.plot(it, dat, "s--", lw=0.8, ms=3, color="0.5", label="data term")
    best = figures["best_iteration"]
    ax.plot([best], [figures["objective_fitted"]], "r*", ms=10, label=f"kept: iteration {best}")
    if min(tot + dat) > 0:
        ax.set_yscale("log")
    else:  # the held-out data term is an unbiased estimate and may dip below 0 near the optimum
        ax.set_yscale("symlog", linthresh=max(1e-3, min(abs(v) for v in tot + dat if v != 0)))
    ax.set_xlabel("iteration")
    ax.set_title(f"objective {figures['objective_start']:.4g} → {figures['objective_fitted']:.4g}", fontsize=9)
    ax.legend(fontsize=7)
    # Colour map before / after, as the leaf albedo each gives, both exposed alike (the painted mean at mid-grey).
    if maps is not None:
        k = 0.18 / max(float(np.mean(luminance(np.asarray(maps[0], np.float64)))), 1e-9)
        for j, (name, m) in enumerate((("painted colour map", maps[0]), ("fitted colour map", maps[1]))):
            ax = fig.add_subplot(gs[2, j])
            ax.imshow(np.clip(linear_to_srgb(np.asarray(m) * k), 0.0, 1.0), origin="lower", interpolation="nearest")
            ax.set_title(
                f"{name} ({m.shape[1]}×{m.shape[0]}) as leaf colour\nrow 0 at the smallest Z; the painted mean "
                "is mid-grey",
                fontsize=9,
            )
            ax.axis("off")
    # Parameter table.
    ax = fig.add_subplot(gs[len(heights) - 1, :])
    ax.axis("off")
    cols = ["parameter", "start", "fitted", "range", "prior", "determined", "flag"]
    cells = [
        [
            r["label"],
            r["start_shown"],
            r["fitted_shown"],
            r["range"],
            r["prior"],
            f"{100 * r['determined']:.0f} %",
            r["flag"]
            .replace("held: undetermined: the reference narrows its prior by", "held: narrowed by")
            .replace(
                "the camera's gain multiplies every light and the lights are fitted: they are one",
                "one with the light level",
            )[:60],
        ]
        for r in table
    ]
    if cells:
        tab = ax.table(
            cellText=cells,
            colLabels=cols,
            loc="upper center",
            cellLoc="left",
            colWidths=[0.2, 0.1, 0.1, 0.14, 0.15, 0.08, 0.23],
        )
        tab.auto_set_font_size(False)
        tab.set_fontsize(8)
        tab.scale(1.0, 1.25)
    fig.text(0.12, (notes_height + 0.05) / total, "\n".join(notes), fontsize=8, va="top", ha="left")
    w, h = size
    fig.suptitle(
        f"forest match — {settings.mode}, {len(history) - 1} iterations × {settings.spp} spp at {w}×{h}; "
        f"fitted: {', '.join(settings.params)}",
        fontsize=11,
    )
    with atomic_path(path) as tmp:
        fig.savefig(str(tmp), format="png", metadata={"Software": None})
    return path
