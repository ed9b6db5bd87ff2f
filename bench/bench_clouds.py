"""The cost of the clouds in forest_path (llvm_ad_rgb): none, the flat layer, and cumulus in height.

    .venv/bin/python bench/bench_clouds.py

The demo scene (configs/demo.toml: fair-weather cumulus over far hills, the horizon on the upper third) at
480x270, 8 spp: the same PathScene inputs without clouds, with the flat layer for every ray
(``[lights.clouds] height = 0``), with cumulus in height spread evenly (``clustering = 0``) and with the
default, where camera rays see cumulus in height gathered in groups (:mod:`forest.render.path.clouds`,
equations (2') and (5)-(7)).  The renders alternate (best of 3 each, after one
warm-up each that compiles the kernels), so a busy machine slows all alike.  Printed: wall and CPU seconds
of ``PathScene.render``, their ratios to the clear sky and of the cumulus to the flat layer, the mean
radiance, and the share of the pixels that see the sky which show cloud (transmittance below ½ along the
pixel centre's ray: the flat layer's, or the cumulus'), and how even the band of far clouds is all around
the horizon: the spread (standard deviation) over 24 sectors of azimuth of the share of clouded rays 1.5-6
degrees up.
"""

from __future__ import annotations

import os
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import best_of, versus


def cloud_share(scene, camera_rays: bool) -> float:
    """Share of the pixels whose centre ray leaves the scene that see cloud (T < ½)."""
    import drjit as dr

    mi = scene.mi
    layer = getattr(scene.lights, "clouds", None)
    if layer is None:
        return 0.0
    camera = scene.inputs.camera
    w, h = int(camera.width), int(camera.height)
    sky = scene.layers()["row"].ravel() < 0
    with dr.suspend_grad():
        idx = dr.arange(mi.UInt32, w * h)
        pos = mi.Point2f((mi.Float(idx % w) + 0.5) / w, (mi.Float(idx // w) + 0.5) / h)
        ray, _ = scene.sensor(camera).sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
        on = mi.Bool(True)
        T = layer.cumulus(ray.o, ray.d, on)[0] if camera_rays else layer.transmittance(ray.o, ray.d, on)[0]
    return float((np.asarray(T)[sky] < 0.5).mean())


def band_spread(scene) -> float:
    """Standard deviation over 24 sectors of azimuth of the share of camera rays 1.5-6 degrees up that see cloud."""
    import drjit as dr

    mi = scene.mi
    layer = scene.lights.clouds
    rng = np.random.default_rng(3)
    az = rng.uniform(0.0, 2.0 * np.pi, 48000)
    el = np.radians(rng.uniform(1.5, 6.0, 48000))
    d = np.stack([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)], 1).astype(np.float32)
    eye = np.asarray(scene.inputs.camera.to_world)[:3, 3]  # from the camera
    with dr.suspend_grad():
        o = mi.Point3f(*map(float, eye))
        T = np.asarray(layer.cumulus(o, mi.Vector3f(*[mi.Float(d[:, k]) for k in range(3)]), mi.Bool(True))[0])
    sector = (az / (2.0 * np.pi) * 24).astype(int)
    return float(np.std([(T[sector == k] < 0.5).mean() for k in range(24)]))


def main() -> None:
    from forest.config import load_config
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_inputs
    from forest.scene import load_scene

    load = os.getloadavg()
    print(f"clouds: load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at start; demo 480x270 8 spp")
    scene = load_scene(load_config(ROOT / "configs" / "demo.toml"))
    inputs = path_inputs(scene, width=480, height=270, spp=8)
    clouds = inputs.sky.clouds
    assert clouds is not None
    variants = {
        "clear sky": replace(inputs, sky=replace(inputs.sky, clouds=None)),
        "flat layer (height = 0)": replace(inputs, sky=replace(inputs.sky, clouds=replace(clouds, height=0.0))),
        "cumulus, even (clustering 0)": replace(
            inputs, sky=replace(inputs.sky, clouds=replace(clouds, clustering=0.0))
        ),
        "cumulus (the default)": inputs,
    }
    names = list(variants)
    scenes = {name: PathScene(inp, "llvm_ad_rgb") for name, inp in variants.items()}
    images, best = best_of({name: (lambda s=s: s.render(seed=1)) for name, s in scenes.items()})
    base_cpu = best[names[0]][1]
    for name in names:
        mean = float(np.asarray(images[name].rgb).mean())  # type: ignore[attr-defined]
        print(f"clouds {name:30s}: {versus(best[name], best[names[0]], 'the clear sky')}, mean {mean:.4f}")
    flat, even, cumulus = scenes[names[1]], scenes[names[2]], scenes[names[3]]
    print(f"clouds: of the pixels that see the sky, {cloud_share(flat, False):.1%} show cloud with the flat layer, "
          f"{cloud_share(even, True):.1%} with even cumulus, {cloud_share(cumulus, True):.1%} with grouped cumulus")  # fmt: skip
    spread_even, spread = band_spread(even), band_spread(cumulus)
    print(f"clouds: far band (1.5-6 deg up, 24 sectors of azimuth), spread of the clouded share: even "
          f"{spread_even:.3f}, grouped {spread:.3f} ({spread / spread_even:.2f}x)")  # fmt: skip
    print(f"clouds cost: cumulus {best[names[3]][1] / best[names[1]][1]:.2f}x CPU of the flat layer, "
          f"{best[names[3]][1] / best[names[2]][1]:.2f}x of even cumulus, "
          f"{best[names[3]][1] / base_cpu:.2f}x of the clear sky")  # fmt: skip
    load = os.getloadavg()
    print(f"clouds: load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at end")


if __name__ == "__main__":
    main()
