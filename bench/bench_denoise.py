"""Denoising (``[render] denoise``): error against a reference at 8–64 spp, plain and denoised, and time.

    .venv/bin/python bench/bench_denoise.py                                   # demo and meadow, 320x180
    .venv/bin/python bench/bench_denoise.py --configs configs/demo.toml --spp 8,16 --crops out/crops
    .venv/bin/python bench/bench_denoise.py --clean-guides --configs cycles --spp 2,4,8,16 --ref-spp 128 --repeat 2
    .venv/bin/python bench/bench_denoise.py --clean-guides --configs configs/demo.toml --size 800x450 --spp 12 --ref-spp 0

For each scene (its still at frame 1 without motion blur, forest_path in ``llvm_ad_rgb``) a reference
of ``--ref-spp`` samples is rendered first with another seed, not denoised; then each spp once plain.
Each run is denoised by Open Image Denoise over the same samples, guided by the frame's first-hit albedo
and normal, in two modes (:data:`MODES`, their order alternating from spp to spp, the machine being
shared): ``guides`` hands OIDN the noisy guides as they are — what ``[render] denoise = true`` writes
(checked: the setting's own frame at the first spp is the same bytes), so its time is the plain run's plus
the denoiser's — and ``prefiltered`` denoises each guide first by a filter of its own and the beauty then
with ``cleanAux`` (``denoise(..., prefilter=True)``, OIDN's recommendation for noisy guides).  Errors:

* relative RMSE of the scene-linear RGB, rRMSE = √(mean over pixels and channels of (I − R)² / (R + 0.01)²).
  The reference's own noise adds to every run's squared error alike (its seed is independent of the
  run's): its share is estimated from the plain run at the largest spp n as e_n² · (n/ref)/(1 + n/ref)
  (the variance of a mean falls as 1/spp) and taken out, err = √(rRMSE² − that);
* mean CIEDE2000 ΔE₀₀ (Sharma, Wu & Dalal 2005) of the display PNGs — the 8-bit sRGB codes through the
  config's view transform and exposure, decoded and taken to CIELAB (D65) with colour-science — against
  the reference's PNG (raw: the reference's noise not removed).

Ratios: denoised / plain error at equal spp, and the spp at which plain reaches the denoised 16-spp error,
from err = c/√spp fitted through the plain runs (rRMSE) and by log-log interpolation (ΔE₀₀).  ``--crops``
writes the reference, plain and both denoised PNGs of a foliage crop (4× nearest) for an eye check, with
the albedo guide as traced and prefiltered.
Seconds are CPU seconds (user + system, every thread) of the frame, the steadier measure on a shared machine.

``--clean-guides``: would clean guides pay?  A first-hit-only guide pass (:func:`clean_guides`: camera rays →
the first hit's albedo, leaf cards' alpha passed as the beauty passes it, and shading normal; no lighting,
bounces or shadow rays) at G = max(``--guide-spp``, spp) samples per pixel, seeded apart from the beauty, then
OIDN with ``cleanAux``.  Printed per spp: the beauty's frame CPU-s (plain, the cheapest of ``--repeat``) beside
the guide pass's, then (``--ref-spp`` > 0) rRMSE plain / old (the beauty's own guides, ``cleanAux`` off: what
``[render] denoise`` does) / new (clean guides), the gain of each (the plain spp of equal error, err = c/√spp,
÷ spp) and the beauty time that the new gain saves (1 − gain_old/gain_new of the frame: an upper bound, the
frame's fixed costs do not shrink) against the guide pass's time.  ``--configs cycles`` is
``bench_cycles.SCENE`` (``--trees``, max_depth 3).  Measured (shared 2-core machine, another test suite
running): the pass costs more than it saves at every spp — the numbers are in docs/rendering.md "Denoising".
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_adaptive import cpu, load, rrmse

ROOT = Path(__file__).resolve().parents[1]


def display(cfg, rgb: np.ndarray) -> np.ndarray:
    """The 8-bit PNG codes of scene-linear ``rgb`` (the config's view and exposure)."""
    from forest.imaging.view import quantise, to_display

    return quantise(to_display(rgb, cfg.render.view, cfg.render.exposure))


def lab(codes: np.ndarray) -> np.ndarray:
    """8-bit sRGB codes → CIELAB (D65)."""
    import colour

    return colour.XYZ_to_Lab(colour.sRGB_to_XYZ(codes.astype(np.float64) / 255.0))


def render(r, cfg, spp: int, denoise: bool = False):
    """(frame image, CPU seconds) of one frame at ``spp`` with ``[render] denoise`` = ``denoise``."""
    object.__setattr__(cfg.render, "denoise", denoise)
    r.spp = spp
    c0 = cpu()
    out = r.frame(1.0)
    return out, cpu() - c0


def interp_spp(spps: list[int], errs: list[float], target: float) -> float:
    """The spp at which the log-log line through (spp, err) reaches ``target`` (extrapolated at the ends)."""
    if len(spps) < 2:
        return math.nan
    x, y = np.log(np.asarray(spps, float)), np.log(np.asarray(errs, float))
    order = np.argsort(-y)  # err falls as spp grows
    x, y = x[order], y[order]
    i = int(np.clip(np.searchsorted(-y, -math.log(target)), 1, len(x) - 1))
    t = (math.log(target) - y[i - 1]) / (y[i] - y[i - 1])
    return float(math.exp(x[i - 1] + t * (x[i] - x[i - 1])))


#: The denoising modes compared, by name: keyword arguments of :func:`forest.imaging.denoise` besides the images.
MODES: dict[str, dict[str, bool]] = {"guides": {"prefilter": False}, "prefiltered": {"prefilter": True}}


def bench_scene(config: Path, width: int, height: int, spps: list[int], ref_spp: int, crops: Path | None) -> None:
    from forest.imaging import denoise
    from forest.imaging.denoise import prefilter_guide
    from forest.render.frame import FrameSize
    from forest.render.render import make_renderer

    t0 = time.perf_counter()
    cfg, scene = load(config, width, height, None, [])
    r = make_renderer(scene, "llvm_ad_rgb", FrameSize(width, height, ref_spp, 1))
    print(f"\n{config.name} {width}x{height}: {len(scene.instances):,} trees, load {time.perf_counter() - t0:.1f} s")
    seed = int(cfg.render.seed)
    object.__setattr__(cfg.render, "seed", seed + 1)  # the reference's noise independent of the runs'
    ref, t_ref = render(r, cfg, ref_spp)
    object.__setattr__(cfg.render, "seed", seed)
    ref_rgb = np.asarray(ref.rgb, np.float64)
    ref_png = display(cfg, ref.rgb)
    ref_lab = lab(ref_png)
    print(f"reference {ref_spp} spp: {t_ref:.1f} CPU-s")
    window = foliage_window(ref.albedo)
    if crops is not None:
        crop_pngs(crops / config.stem, window, {"reference": ref_png, "reference_albedo": guide_png(ref.albedo)})
    import colour

    def delta_e(png: np.ndarray) -> float:
        return float(np.mean(colour.delta_E(lab(png), ref_lab, method="CIE 2000")))

    names = list(MODES)
    rows = []  # (spp, plain CPU-s, plain rRMSE, plain ΔE, {mode: (CPU-s, rRMSE, ΔE)})
    for i, spp in enumerate(spps):
        out, t = render(r, cfg, spp)
        per: dict[str, tuple[float, float, float]] = {}
        pngs = {f"{spp:03d}_plain": display(cfg, out.rgb), f"{spp:03d}_albedo_noisy": guide_png(out.albedo)}
        for name in names if i % 2 == 0 else names[::-1]:  # alternate the order: the machine is shared
            c0 = cpu()
            d = denoise(out.rgb, out.albedo, out.normal, **MODES[name])
            t_d = cpu() - c0
            assert d is not None, "Open Image Denoise (pyoidn) is not installed"
            png = display(cfg, d)
            per[name] = (t_d, rrmse(d, ref_rgb), delta_e(png))
            pngs[f"{spp:03d}_{name}"] = png
            if i == 0 and name == "guides":  # the setting's own frame is the same image
                on, _ = render(r, cfg, spp, denoise=True)
                assert on.denoised and np.array_equal(on.rgb, d), "[render] denoise = true differs from denoise()"
        pngs[f"{spp:03d}_albedo_prefiltered"] = guide_png(prefilter_guide("albedo", out.albedo))
        rows.append((spp, t, rrmse(np.asarray(out.rgb, np.float64), ref_rgb), delta_e(pngs[f"{spp:03d}_plain"]), per))
        if crops is not None:
            crop_pngs(crops / config.stem, window, pngs)
    n, e_n = rows[-1][0], rows[-1][2]
    floor2 = e_n**2 * (n / ref_spp) / (1.0 + n / ref_spp)  # the reference's own noise, squared

    def corr(e: float) -> float:
        return math.sqrt(max(e * e - floor2, 0.0))

    print(f"reference noise (rRMSE, estimated from the {n}-spp run): {math.sqrt(floor2):.4f}, taken out below")
    print(
        f"{'spp':>4} | {'plain CPU-s':>11} "
        + " ".join(f"{'+' + m:>12}" for m in names)
        + f" | {'rRMSE plain':>11} "
        + " ".join(f"{m:>12} {'ratio':>5}" for m in names)
        + f" | {'ΔE00 plain':>10} "
        + " ".join(f"{m:>12} {'ratio':>5}" for m in names)
    )
    for spp, t, ep, dp, per in rows:
        print(
            f"{spp:4d} | {t:11.2f} "
            + " ".join(f"{per[m][0]:12.2f}" for m in names)
            + f" | {corr(ep):11.4f} "
            + " ".join(f"{corr(per[m][1]):12.4f} {corr(per[m][1]) / corr(ep):5.2f}" for m in names)
            + f" | {dp:10.3f} "
            + " ".join(f"{per[m][2]:12.3f} {per[m][2] / dp:5.2f}" for m in names)
        )
    c = math.exp(sum(math.log(corr(ep) * math.sqrt(s)) for s, _, ep, _, _ in rows) / len(rows))
    d16 = next((row for row in rows if row[0] == 16), rows[0])
    for m in names:
        e_d16 = corr(d16[4][m][1])
        spp_rr = (c / e_d16) ** 2 if e_d16 > 0 else math.inf
        spp_de = interp_spp([row[0] for row in rows], [row[3] for row in rows], d16[4][m][2])
        print(
            f"{m}: plain reaches the denoised {d16[0]}-spp error at ≈ {spp_rr:.0f} spp by rRMSE (fit err = "
            f"{c:.3f}/√spp), ≈ {spp_de:.0f} spp by ΔE00 (log-log through the plain runs); denoising costs "
            f"{np.mean([row[4][m][0] for row in rows]):.2f} CPU-s a frame"
        )


def cycles_scene(tmp: Path, count: int, width: int, height: int, spp: int, depth: int, seed: int) -> Path:
    """``bench_cycles.SCENE`` (``count`` trees, sun and sky) written as a config under ``tmp``."""
    from bench_cycles import SCENE

    size = float(np.sqrt(count / 130_000.0) * 4000.0)
    path = tmp / f"cycles_{count}.toml"
    path.write_text(
        SCENE.format(
            size=size, count=count, camz=-0.5 * size, width=width, height=height, spp=spp, depth=depth, seed=seed
        )
    )
    return path


#: The clean-guide pass's seeds: its samples independent of the beauty's (np.random.SeedSequence([seed, TAG, pass])).
GUIDE_SEED_TAG = 0x4755_4944  # "GUID"


def guide_kernel(kernel, sampler, ray, active):
    """The denoiser's guides of each camera ray as the beauty's first vertex defines them, and nothing else.

    (albedo, shading normal facing the camera) with the conventions of ``PathKernel.sample``'s ``aux``:
    the albedo R + T of the surface met first (cut-out texels passed stochastically, as the beauty's rays
    pass them; a water hit's diffuse part 1 − W·F(μ), as the beauty's vertex has it), or where the ray
    leaves the scene the sky's radiance through the haze clipped to [0, 1].  No lighting, no bounce, no
    shadow ray: one traversal (plus the skipped texels) and one shading lookup per lane.
    """
    import drjit as dr

    from forest.render.path.materials import shading, water_coverage, water_lobe

    mi = kernel.mi
    n = dr.width(ray.d)
    seed = dr.reinterpret_array(mi.UInt32, sampler.next_1d())
    rng = mi.PCG32(size=n, initstate=mi.UInt64(seed), initseq=mi.UInt64(dr.arange(mi.UInt32, n)))
    o, d = mi.Point3f(ray.o), mi.Vector3f(ray.d)
    valid, _, row, p, n_geo, n_sh, uv, material, _ = kernel.trace(o, d, ray.maxt, rng, active)
    wi = -d
    flip = dr.dot(n_sh, wi) < 0.0
    ns = dr.select(flip, -n_sh, n_sh)
    k = kernel
    sh = shading(mi, k.mats, material, uv, p, k.grid, k.extent, k.terrain_map, valid, row, k.row_tint)
    if k.water_ripple is not None:
        w = water_coverage(mi, k.mats, material, p, k.terrain_map, valid)
        sh = water_lobe(mi, sh, w, p, wi, dr.select(flip, -n_geo, n_geo), k.water_ripple).shading
    sky = k.lights.eval(d, active & ~valid, o)
    if k.haze is not None:
        sky = sky * k.haze.transmittance(o, d, dr.minimum(ray.maxt, k.haze.sky_distance))
    albedo = dr.select(valid, sh.reflect + sh.transmit, dr.clip(sky, 0.0, 1.0))
    return albedo, dr.select(valid, ns, 0.0)


def clean_guides(path, camera, spp: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(albedo, normal) (H, W, 3) float32 of a ``PathScene``: the mean over ``spp`` camera samples per pixel of
    :func:`guide_kernel`, a pass of its own seeded from ``seed`` and :data:`GUIDE_SEED_TAG` (the normal not
    renormalised, as the beauty's guide)."""
    import drjit as dr

    from forest.render.path.frame import mi_bool, pixel_sums, split_passes

    w, h = int(camera.width), int(camera.height)
    kernel = path.kernel()
    albedo, normal, total = np.zeros((h * w, 3)), np.zeros((h * w, 3)), 0
    with dr.suspend_grad():
        for k, n in enumerate(split_passes(w, h, int(spp), path.max_lanes)):
            s = int(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, GUIDE_SEED_TAG, k]).generate_state(1)[0])
            sampler, ray, used = path._camera_rays(camera, n, s)
            alb, nrm = guide_kernel(kernel, sampler, ray, mi_bool(path.mi, True))
            dr.eval(alb, nrm)
            albedo += pixel_sums(path.mi, alb, used, h * w)
            normal += pixel_sums(path.mi, nrm, used, h * w)
            total += used
    return tuple((a / total).reshape(h, w, 3).astype(np.float32) for a in (albedo, normal))  # type: ignore[return-value]


def bench_clean_guides(
    config: Path, width: int, height: int, spps: list[int], ref_spp: int, guide_min: int, repeat: int
) -> None:
    """The clean-guide pass (:func:`clean_guides` at G = max(``guide_min``, spp), OIDN with ``cleanAux``): its
    CPU seconds beside the beauty's, and — with ``ref_spp`` > 0 — the error of plain, old (the beauty's own
    guides) and new (clean guides) denoising, with the plain spp each is worth (err = c/√spp)."""
    from forest.imaging import denoise
    from forest.render.frame import FrameSize
    from forest.render.path.from_scene import path_camera
    from forest.render.render import make_renderer

    t0 = time.perf_counter()
    cfg, scene = load(config, width, height, None, [])
    r = make_renderer(scene, "llvm_ad_rgb", FrameSize(width, height, max(spps), 1))
    seed = int(cfg.render.seed)
    print(
        f"\n{config.name} {width}x{height}: {len(scene.instances):,} trees, max_depth {cfg.render.max_depth}, "
        f"load {time.perf_counter() - t0:.1f} s"
    )
    camera = path_camera(cfg, 1.0, width, height)

    def guides(g: int) -> tuple[np.ndarray, np.ndarray, float]:
        c0 = cpu()
        a, n = clean_guides(r.path, camera, g, seed)
        return a, n, cpu() - c0

    render(r, cfg, min(spps))  # compile the kernels before timing anything
    guides(guide_min)
    rows = []  # (spp, G, beauty CPU-s, guide CPU-s, out, clean albedo, clean normal)
    for spp in spps:
        g = max(guide_min, spp)
        t_b, t_g = math.inf, math.inf
        for _ in range(repeat):  # the cheapest of ``repeat``, alternating (the machine is shared)
            out, t = render(r, cfg, spp)
            t_b = min(t_b, t)
            alb, nrm, t = guides(g)
            t_g = min(t_g, t)
        rows.append((spp, g, t_b, t_g, out, alb, nrm))
    print(f"{'spp':>4} {'G':>3} | {'beauty CPU-s':>12} {'guide CPU-s':>11} {'guide/beauty':>12} | break-even gain")
    for spp, g, t_b, t_g, *_ in rows:
        print(f"{spp:4d} {g:3d} | {t_b:12.2f} {t_g:11.2f} {t_g / t_b:12.2f} | {t_g / t_b * 100:5.0f} % of the beauty")
    if ref_spp <= 0:
        return
    object.__setattr__(cfg.render, "seed", seed + 1)  # the reference's noise independent of the runs'
    ref, t_ref = render(r, cfg, ref_spp)
    object.__setattr__(cfg.render, "seed", seed)
    ref_rgb = np.asarray(ref.rgb, np.float64)
    print(f"reference {ref_spp} spp: {t_ref:.1f} CPU-s")
    errs = []  # (spp, plain, old, new)
    for spp, _g, _tb, _tg, out, alb, nrm in rows:
        old = denoise(out.rgb, out.albedo, out.normal)
        new = denoise(out.rgb, alb, nrm, clean_aux=True)
        assert old is not None and new is not None, "Open Image Denoise (pyoidn) is not installed"
        errs.append((spp, *(rrmse(np.asarray(x, np.float64), ref_rgb) for x in (out.rgb, old, new))))
    n, e_n = errs[-1][0], errs[-1][1]
    floor2 = e_n**2 * (n / ref_spp) / (1.0 + n / ref_spp)  # the reference's own noise, squared

    def corr(e: float) -> float:
        return math.sqrt(max(e * e - floor2, 0.0))

    c = math.exp(sum(math.log(corr(e) * math.sqrt(s)) for s, e, _, _ in errs) / len(errs))
    print(f"reference noise (rRMSE): {math.sqrt(floor2):.4f}, taken out; plain fit err = {c:.3f}/√spp")
    print(f"{'spp':>4} | {'rRMSE plain':>11} {'old':>7} {'new':>7} | {'gain old':>8} {'new':>6} | samples saved")
    for (spp, ep, eo, en), (_, g, t_b, t_g, *_) in zip(errs, rows, strict=True):
        go, gn = (c / corr(eo)) ** 2 / spp, (c / corr(en)) ** 2 / spp
        print(
            f"{spp:4d} | {corr(ep):11.4f} {corr(eo):7.4f} {corr(en):7.4f} | {go:7.2f}x {gn:5.2f}x | "
            f"{(1 - go / gn) * 100:4.0f} % of the beauty ({(1 - go / gn) * t_b:.2f} CPU-s) vs the {g}-spp guide "
            f"pass {t_g:.2f} CPU-s"
        )


def guide_png(albedo: np.ndarray) -> np.ndarray:
    """8-bit codes of an albedo guide (sRGB-encoded, as a texture is seen)."""
    a = np.clip(np.asarray(albedo, np.float64)[..., :3], 0.0, 1.0)
    s = np.where(a <= 0.0031308, 12.92 * a, 1.055 * a ** (1 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)


def foliage_window(albedo: np.ndarray, h: int = 54, w: int = 96) -> tuple[int, int]:
    """(y, x) of the ``w``×``h`` window with the most albedo detail (summed gradient; a coarse search)."""
    a = np.asarray(albedo, np.float64).mean(axis=2)
    g = np.abs(np.diff(a, axis=0))[:, :-1] + np.abs(np.diff(a, axis=1))[:-1, :]
    best, at = -1.0, (0, 0)
    for y in range(0, max(1, g.shape[0] - h), 9):
        for x in range(0, max(1, g.shape[1] - w), 16):
            s = float(g[y : y + h, x : x + w].sum())
            if s > best:
                best, at = s, (y, x)
    return at


def crop_pngs(folder: Path, window: tuple[int, int], images: dict[str, np.ndarray]) -> None:
    """The 96×54 crop at ``window`` of each display image, 4× nearest, as ``<name>.png``."""
    from forest.images import write_encoded_image

    folder.mkdir(parents=True, exist_ok=True)
    (y, x), h, w = window, 54, 96
    for name, img in images.items():
        c = np.repeat(np.repeat(img[y : y + h, x : x + w], 4, axis=0), 4, axis=1)
        write_encoded_image(folder / f"{name}.png", c)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configs", default="configs/demo.toml,configs/meadow.toml")
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--spp", default="8,16,32,64")
    ap.add_argument("--ref-spp", type=int, default=256)
    ap.add_argument("--crops", type=Path, default=None, help="folder for foliage crops (plain, denoised, reference)")
    ap.add_argument(
        "--clean-guides",
        action="store_true",
        help="the clean-guide pass instead: its cost beside the beauty's, and the gain (old vs new denoising); "
        "--configs may name 'cycles' (bench_cycles.SCENE, --trees trees, max_depth 3)",
    )
    ap.add_argument("--trees", type=int, default=2000)
    ap.add_argument("--guide-spp", type=int, default=16, help="G = max(this, spp) guide samples per pixel")
    ap.add_argument("--repeat", type=int, default=1, help="timed runs per spp (the cheapest is kept)")
    args = ap.parse_args()
    from forest.imaging import oidn_available

    if not oidn_available():
        sys.exit("bench_denoise: needs Open Image Denoise (pip install pyoidn)")
    width, height = (int(v) for v in args.size.split("x"))
    spps = [int(s) for s in args.spp.split(",")]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="forest-bench-denoise-") as tmp:
        for c in args.configs.split(","):
            path = Path(c) if Path(c).is_absolute() else ROOT / c
            if c == "cycles":
                path = cycles_scene(Path(tmp), args.trees, width, height, max(spps), 3, 5)
            if args.clean_guides:
                bench_clean_guides(path, width, height, spps, args.ref_spp, args.guide_spp, args.repeat)
            else:
                bench_scene(path, width, height, spps, args.ref_spp, args.crops)
    print(f"\nwall {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
