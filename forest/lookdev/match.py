"""``match``: fit a Scene's look to a reference photo with the production renderer.

The steps, each in its own module:

1. settings from the call over ``[lookdev]`` (:func:`resolve_settings`);
2. the reference read, checked, cropped and resampled to the fit's size, with
   its painted regions if any (:mod:`.reference`, :mod:`.regions`);
3. the production scene built once for the fit (:mod:`.renders`): all trees,
   reduced resolution and samples;
4. the parameters, their ranges and priors (:mod:`.params`), the data term —
   noise-weighted pixels (aligned) or region colour statistics (statistics) —
   (:mod:`.losses`), and the image model (:mod:`.image_model`);
5. the Gauss–Newton loop with its guard rails (:mod:`.fit`, :mod:`.solve`);
6. the outputs (:mod:`.report`): ``scene.toml`` with every fitted value folded
   in (camera exposure and white balance go into the lights, exactly), the
   colour map at the painted map's resolution, ``sky.exr`` for a tilted sky,
   ``report.png`` with production renders of the start and the result, and
   ``match.json``.
"""

from __future__ import annotations

import time
import warnings as _warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..config import Config, ConfigError
from ..errors import ParameterError
from .params import DEFAULT_GROUPS, GROUPS, Look, specs_for, start_values

if TYPE_CHECKING:
    from ..scene import Scene
    from .solve import Problem

MODES = ("aligned", "statistics")
SEED_TAG = 0x100CDE7


@dataclass
class Settings:
    """A fit's settings: the ``[lookdev]`` table with the caller's overrides applied (:func:`resolve_settings`)."""

    iterations: int
    resolution: int
    spp: int
    params: tuple[str, ...]
    mode: str
    grid: int | str  # cells per side, or "auto" (chosen from the fit's render: :func:`auto_grid`)
    fresh_map: bool
    mask: Path | None
    fit: str
    variant: str
    report_width: int
    anchor: str = "auto"
    map_prior: str = "edges"
    #: Why ``variant`` when it was chosen automatically (:func:`forest.render.variant.default_jit_variant`), else "".
    variant_reason: str = ""


@dataclass
class MatchResult:
    """What ``match`` wrote and what it found."""

    out_dir: Path
    scene_path: Path
    colour_map_path: Path | None
    report_path: Path
    json_path: Path
    table: list[dict[str, Any]]  # every parameter: name, label, start, fitted, range, prior, determination, flag
    figures: dict[str, Any]
    fitted: tuple[str, ...]
    variant: str
    seconds: float
    warnings: list[str] = field(default_factory=list)
    losses: list[float] = field(default_factory=list)
    held_cells: np.ndarray | None = None  # (grid, grid) bool: colour-map cells unseen, kept as painted
    cell_information: np.ndarray | None = None  # (grid, grid): the reference's information on each cell (prior units)
    grid: int | None = None  # the colour map's cells per side (fitted maps)
    anchor: str = "none"  # what held the scale of albedos against light
    weak: list[str] = field(default_factory=list)  # the weak directions, described

    @property
    def paths(self) -> list[Path]:
        """The files written: scene, colour map (when fitted), report and JSON."""
        return [p for p in (self.scene_path, self.colour_map_path, self.report_path, self.json_path) if p]


def parse_params(value: str | Iterable[str], where: str = "lookdev.params") -> tuple[str, ...]:
    """``"camera,sun"`` or a list → validated tuple of parameter groups."""
    items = value.split(",") if isinstance(value, str) else list(value)
    out: list[str] = []
    for it in items:
        it = str(it).strip()
        if not it:
            continue
        if it not in GROUPS:
            raise ParameterError(where, f"unknown parameter {it!r} (expected some of {', '.join(GROUPS)})")
        if it not in out:
            out.append(it)
    if not out:
        raise ParameterError(where, f"give at least one of {', '.join(GROUPS)}")
    return tuple(out)


def resolve_settings(
    config: Config,
    *,
    iterations: int | None = None,
    resolution: int | None = None,
    spp: int | None = None,
    params: str | Iterable[str] | None = None,
    mode: str | None = None,
    mask: str | Path | None = None,
    variant: str | None = None,
    grid: int | str | None = None,
    anchor: str | None = None,
    map_prior: str | None = None,
    pick_variant: bool = True,
) -> Settings:
    """Call arguments over ``[lookdev]`` over its defaults, validated by the scene schema (errors name
    ``lookdev.<option>``).

    Without a variant given or configured, the automatic choice (the GPU where it passed its self-check, else
    ``llvm_ad_rgb``); ``pick_variant=False`` (a check of the settings alone, as the job service makes on
    submission) leaves ``variant`` ``"auto"`` instead, so that no GPU self-check runs."""
    if isinstance(grid, str) and grid.strip().isdigit():
        grid = int(grid)
    given: dict[str, Any] = {
        "iterations": iterations,
        "resolution": resolution,
        "spp": spp,
        "mode": mode,
        "grid": grid,
        "variant": variant,
        "anchor": anchor,
        "map_prior": map_prior,
    }
    if params is not None:
        parse_params(params)
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
    groups = parse_params(lk.params) if lk.params is not None else DEFAULT_GROUPS[lk.mode]
    if lk.mode == "statistics" and "colour_map" in groups:
        groups = tuple(g for g in groups if g != "colour_map")  # an unrelated photo cannot place colours
    v: str
    why = ""
    if lk.variant is not None:
        v = lk.variant
    elif not pick_variant:
        v = "auto"
    else:
        from ..render.variant import default_jit_variant

        v, why = default_jit_variant()
    return Settings(
        iterations=lk.iterations,
        resolution=lk.resolution,
        spp=lk.spp,
        params=groups,
        mode=lk.mode,
        grid=lk.grid,
        fresh_map=lk.fresh_map,
        mask=lk.mask,
        fit=lk.fit,
        variant=v,
        variant_reason=why,
        report_width=lk.report_width,
        anchor=lk.anchor,
        map_prior=lk.map_prior,
    )


#: ``grid = "auto"``: the finest grid whose cells that hold trees have on average at least this many canopy pixels.
MIN_CELL_PIXELS = 24
#: Grids ``auto`` chooses among (cells per side).
AUTO_GRIDS = (64, 48, 32, 24, 16, 12, 8, 6, 4, 3, 2, 1)
#: ``anchor = "auto"`` in aligned mode anchors on the ground when at least this share of the frame shows it.
ANCHOR_MIN_GROUND = 0.02


def auto_grid(layers: dict[str, np.ndarray], labels: np.ndarray) -> tuple[int, str]:
    """(cells per side, a note saying why) for ``grid = "auto"``: the finest of :data:`AUTO_GRIDS` whose cells
    that hold canopy pixels of the fit's render hold on average at least :data:`MIN_CELL_PIXELS` of them (a cell
    seen by fewer is decided more by the render's noise than by the reference)."""
    from .regions import CANOPY

    canopy = labels == CANOPY
    u, v = layers["u"][canopy], layers["v"][canopy]
    ok = np.isfinite(u) & np.isfinite(v)
    u, v = np.clip(u[ok], 0.0, 1.0 - 1e-9), np.clip(v[ok], 0.0, 1.0 - 1e-9)
    for n in AUTO_GRIDS:
        counts = np.bincount((v * n).astype(np.int64) * n + (u * n).astype(np.int64), minlength=n * n)
        held = counts[counts > 0]
        mean = float(held.mean()) if held.size else 0.0
        if n == 1 or mean >= MIN_CELL_PIXELS:
            return n, (
                f"colour map fitted on {n}×{n} cells: the finest grid whose cells that hold trees have on average "
                f"at least {MIN_CELL_PIXELS} canopy pixels of the fit's {labels.shape[1]}×{labels.shape[0]} render "
                f"({mean:.0f}, {held.size} cells hold trees); --grid sets it"
            )
    raise AssertionError("unreachable: n = 1 always qualifies")


def resolve_anchor(anchor: str, mode: str, labels: np.ndarray) -> str:
    """``auto`` → ``ground`` (aligned, the frame shows ground in ≥ :data:`ANCHOR_MIN_GROUND` of it), ``leaves``
    (aligned otherwise) or ``none`` (statistics); other values as given."""
    from .regions import GROUND

    if anchor != "auto":
        return anchor
    if mode != "aligned":
        return "none"
    return "ground" if float(np.mean(labels == GROUND)) >= ANCHOR_MIN_GROUND else "leaves"


ANCHOR_TEXT = {
    "ground": "the ground keeps the scene's albedo",
    "leaves": "the leaves keep the species' measured colours (and the colour map its mean)",
    "lights": "the lights keep the scene's level",
    "none": "nothing holds it; the priors decide",
}


def hold_degenerate(problem: Problem, anchor: str) -> list[str]:
    """Hold what the image cannot tell apart, by construction (:mod:`.params`): the camera when the lights are
    fitted (exactly one thing), and the anchor's side of albedos against light.  Returns notes for the user."""
    names = {s.name for s in problem.specs}
    notes: list[str] = []

    def hold(name: str, why: str) -> None:
        if name in names and name not in problem.held:
            problem.held.add(name)
            problem.held_reasons[name] = why

    if "light_level" in names:
        for name in ("exposure", "wb_mired", "wb_tint"):
            hold(name, "the camera's gain multiplies every light and the lights are fitted: they are one")
    if anchor == "ground":
        for ch in "rgb":
            hold(f"ground_{ch}", "the anchor (lookdev.anchor = ground)")
    elif anchor == "leaves":
        for ch in "rgb":
            hold(f"leaves_{ch}", "the anchor (lookdev.anchor = leaves)")
    elif anchor == "lights":
        hold("light_level", "the anchor (lookdev.anchor = lights)")
    problem.anchor = anchor
    notes.append(f"anchor of the scale of albedos against light: {ANCHOR_TEXT[anchor]} (--anchor changes it)")
    return notes


def optimiser_size(config: Config, resolution: int) -> tuple[int, int]:
    """(width, height) with the long side ``resolution`` and the render's aspect ratio."""
    w, h = config.render.width, config.render.height
    if w >= h:
        return resolution, max(1, round(resolution * h / w))
    return max(1, round(resolution * w / h)), resolution


def match(
    scene: Scene,
    reference: str | Path | np.ndarray,
    out_dir: str | Path,
    *,
    iterations: int | None = None,
    resolution: int | None = None,
    spp: int | None = None,
    params: str | Iterable[str] | None = None,
    mode: str | None = None,
    mask: str | Path | None = None,
    variant: str | None = None,
    progress: Callable[[float, str], None] | None = None,
    grid: int | str | None = None,
    seed: int | None = None,
    anchor: str | None = None,
    map_prior: str | None = None,
) -> MatchResult:
    """Fit the look of a :class:`~forest.scene.Scene` to ``reference`` (an image path or an (H, W, 3) linear
    array) and write the results to ``out_dir``; ``progress(fraction, message)`` follows the fit."""
    from ..runtime import mitsuba
    from .correction import base_map
    from .fit import Fitter
    from .image_model import ImageModel
    from .losses import PixelLoss, RegionLoss
    from .reference import load_reference, painted_labels
    from .regions import AUTO, CANOPY, GROUND, SKY, photo_labels, regions, render_labels
    from .renders import FitRenderer
    from .report import write_outputs
    from .solve import Problem

    t0 = time.perf_counter()
    say: Callable[[float, str], None] = progress or (lambda _f, _m: None)
    config = scene.config
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
        anchor=anchor,
        map_prior=map_prior,
    )
    mitsuba(st.variant)
    width, height = optimiser_size(config, st.resolution)
    notes: list[str] = []
    with _warnings.catch_warnings(record=True) as caught:
        _warnings.simplefilter("always")
        ref = load_reference(reference, width, height, mask=None, fit=st.fit)
    notes += [str(w.message) for w in caught]
    painted = None if st.mask is None else painted_labels(st.mask, ref, width, height, st.fit)
    groups = set(st.params)
    fit_map = "colour_map" in groups and st.mode == "aligned"
    painted_map = None if scene.colour is None else scene.colour.rgb
    say(0.01, "building the production scene")
    renderer = FitRenderer(
        scene,
        width=width,
        height=height,
        spp=st.spp,
        variant=st.variant,
        base_map=painted_map if painted_map is not None or not fit_map else np.ones((1, 1, 3)),
        haze="haze" in groups,
    )
    start = renderer.start
    lay = renderer.layers
    rl = render_labels(lay)
    cells: tuple[int, int] | None = None
    base = None if painted_map is None else np.asarray(painted_map, np.float64)
    if fit_map:
        if st.grid == "auto":
            n, grid_note = auto_grid(lay, rl)
            notes.append(grid_note)
        else:
            n = int(st.grid)
        cells = (n, n)
        base = base_map(painted_map, cells, st.fresh_map)
    sky_px = ~lay["hit"]
    from .params import GRADIENT_MIN_ELEVATION, HORIZON_BAND_AT_TOP, horizon_band_exponent

    top = float(lay["dir"][..., 1][sky_px].max()) if sky_px.any() else -1.0
    start.sky_tied = top <= 0.0
    if "sky" in groups and start.sky_kind == "constant":
        if start.sky_tied:
            notes.append("no sky in frame: its gradient is held, the sky is fitted as one colour")
        elif (k := horizon_band_exponent(top)) > 1.0:
            start.sky_exponent = k
            renderer.set_sky_exponent(k)
            notes.append(
                f"the sky in frame reaches {np.degrees(np.arcsin(min(top, 1.0))):.0f}° above the horizon "
                f"(under {GRADIENT_MIN_ELEVATION:g}°): the horizon colour is fitted as a band (1 − μ)^"
                f"{start.sky_exponent:.3g} that fades to {HORIZON_BAND_AT_TOP:g} at the top of the frame, the zenith "
                "colour as the sky above it"
            )
    specs = specs_for(start, groups)
    look0 = Look(start_values(start, specs), np.zeros((*cells, 3)) if cells is not None else None)
    image = ImageModel(lay["optical"], clip=ref.display_referred)
    rseed = int(config.seed if seed is None else seed)
    problem = Problem(specs, start, image, None, renderer.n_species, cells=cells, map_prior=st.map_prior)
    anchor = resolve_anchor(st.anchor, st.mode, rl)
    notes += hold_degenerate(problem, anchor)
    if st.mode == "statistics":
        # One photo of another place shows the product of the camera's balance and the colours it lit.
        for name in ("wb_mired", "wb_tint"):
            if any(s.name == name for s in specs) and name not in problem.held:
                problem.held.add(name)
                problem.held_reasons[name] = "confounded with the light colours in an unrelated photo"
    problem.map_mean_fixed = fit_map and (anchor == "leaves" or any(s.name.startswith("leaves_") for s in problem.free))
    fitter = Fitter(renderer, problem, base_map=base, seed=rseed ^ SEED_TAG)
    # The start's image and where its sun reaches: regions, and the noise of the aligned loss.
    fitter.apply(look0)
    u0 = renderer.light_images(rseed + 1)
    scales = problem.light_scales(look0)
    total0 = sum(u0[k] * s for k, s in scales.items() if k in u0)
    sun_lit = None
    if "sun_irradiance" in u0 and "sun_irradiance" in scales:
        sun_part = u0["sun_irradiance"] * scales["sun_irradiance"]
        sun_lit = (sun_part.sum(-1) >= 0.5 * np.maximum(total0.sum(-1), 1e-9)) & lay["hit"]
    start_photo = problem.photo_model(look0, total0)
    if st.mode == "aligned":  # the same camera: the render's regions are the photo's, unless painted
        pl = rl if painted is None else np.where(painted == AUTO, rl, painted)
    else:  # the render of the same view teaches the segmentation what tells its ground from its canopy
        pl = photo_labels(ref.rgb, rl, painted, render_rgb=start_photo)
    loss: PixelLoss | RegionLoss
    if st.mode == "aligned":
        loss = PixelLoss(ref)
        other = problem.photo_model(look0, fitter.render(look0, rseed + 2))
        from scipy.ndimage import uniform_filter

        var = uniform_filter((start_photo - other) ** 2 / 2.0, size=(3, 3, 1), mode="nearest")
        loss.set_noise(var)
        loss.mask(pl >= 0)
        loss.set_groups(pl, {SKY: "sky", CANOPY: "canopy", GROUND: "ground"})
    else:
        sky_up = lay["dir"][..., 1]
        regs = regions(rl, pl, sky_up=sky_up, sun_lit=sun_lit, render_img=start_photo, photo_img=ref.rgb)
        loss = RegionLoss(ref.rgb, regs)
    problem.loss = loss
    say(0.05, "fitting")
    res = fitter.run(look0, iterations=st.iterations, progress=lambda f, m: say(0.05 + 0.75 * f, m))
    notes += res.warnings
    say(0.82, "writing and rendering the report")
    out = write_outputs(
        Path(out_dir),
        scene=scene,
        settings=st,
        renderer=renderer,
        problem=problem,
        fitter=fitter,
        result=res,
        reference=ref,
        photo_labels=pl,
        render_labels=rl,
        notes=notes,
        seconds=time.perf_counter() - t0,
        seed=rseed,
        sun_lit=sun_lit,
    )
    say(1.0, "done")
    return MatchResult(
        out_dir=Path(out_dir),
        scene_path=out["scene"],
        colour_map_path=out.get("colour_map"),
        report_path=out["report"],
        json_path=out["json"],
        table=out["table"],
        figures=out["figures"],
        fitted=tuple(sorted(groups)),
        variant=st.variant,
        seconds=time.perf_counter() - t0,
        warnings=notes,
        losses=[h["total"] for h in res.history],
        held_cells=None if problem.held_cells is None or cells is None else problem.held_cells.reshape(cells),
        cell_information=res.cell_information,
        grid=None if cells is None else cells[0],
        anchor=problem.anchor,
        weak=out["weak"],
    )
