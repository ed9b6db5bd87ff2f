"""Regenerate the example maps under configs/maps/ (deterministic; the PNGs are committed).

    .venv/bin/python configs/make_maps.py

Map convention: column → +X, row → +Z (row 0 at the smallest Z), laid over the
terrain's X/Z extent.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from forest.terrain import fbm_heights

HERE = Path(__file__).resolve().parent / "maps"
N = 256


def save(name: str, img: np.ndarray, bits: int = 8) -> None:
    img = np.clip(img, 0.0, 1.0)
    if img.ndim == 2:
        img = img[..., None]
    fmt = oiio.UINT16 if bits == 16 else oiio.UINT8
    data = np.round(img * (65535 if bits == 16 else 255)).astype(np.uint16 if bits == 16 else np.uint8)
    spec = oiio.ImageSpec(img.shape[1], img.shape[0], img.shape[2], fmt)
    out = oiio.ImageOutput.create(str(HERE / name))
    out.open(str(HERE / name), spec)
    out.write_image(data)
    out.close()


def river_mask(n: int, seed: int, width: float) -> np.ndarray:
    """Distance (in map units) to a meandering river running along +Z."""
    rng = np.random.default_rng(seed)
    z = np.linspace(0, 1, n)
    centre = 0.5 + sum(
        a * np.sin(2 * np.pi * (f * z + p))
        for a, f, p in zip(rng.uniform(0.03, 0.09, 3), (0.7, 1.6, 3.1), rng.random(3))
    )
    x = np.linspace(0, 1, n)
    return np.abs(x[None, :] - centre[:, None]) / width


def lake_basin(height: np.ndarray, centre, radii, depth: float) -> np.ndarray:
    """The terrain lowered by a smooth bowl: ``depth`` (of full white) at ``centre`` (u, v), falling as
    (1 − (r/2)²)² to nothing at twice the elliptical ``radii``; the demo's lake fills it to a level."""
    n = height.shape[0]
    t = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(t, t)
    r = np.hypot((u - centre[0]) / radii[0], (v - centre[1]) / radii[1])
    return height - depth * np.clip(1.0 - (r / 2.0) ** 2, 0.0, 1.0) ** 2


def main() -> None:
    HERE.mkdir(parents=True, exist_ok=True)
    height = fbm_heights(N, 6, 0.5, seed=11)
    dist = river_mask(N, 5, 0.03)
    valley = np.clip(dist / 3.0, 0, 1) ** 0.7  # the river runs in a valley
    height = 0.15 + 0.85 * height * (0.35 + 0.65 * valley)
    save("height.png", height, bits=16)
    save("demo_height.png", lake_basin(height, (0.47, 0.27), (0.2, 0.11), 0.5), bits=16)
    save("presence.png", (dist > 1.0).astype(np.float32))
    dens = fbm_heights(N, 4, 0.6, seed=23)
    save("density.png", 0.25 + 0.75 * dens)
    # Colour: autumn patches over green.
    t = fbm_heights(N, 5, 0.55, seed=31)[..., None]
    green = np.array([0.45, 0.62, 0.32])
    warm = np.array([0.85, 0.55, 0.25])
    save("colour.png", green * (1 - t**2) + warm * t**2)
    # Partitions by distance from the camera side (-Z): foreground, midground, background.
    zz = np.linspace(0, 1, N)[:, None] * np.ones((1, N))
    part = np.zeros((N, N, 3))
    part[zz < 0.33] = (1, 0, 0)
    part[(zz >= 0.33) & (zz < 0.66)] = (0, 1, 0)
    part[zz >= 0.66] = (0, 0, 1)
    save("partition.png", part)

    jungle()
    city()
    meadow()


def jungle() -> None:
    """Jungle with river paths: a braided river carved out by the presence map."""
    height = fbm_heights(N, 6, 0.55, seed=41)
    d1 = river_mask(N, 7, 0.025)
    d2 = river_mask(N, 13, 0.015).T  # a tributary running along +X
    dist = np.minimum(d1, d2)
    save("jungle_height.png", 0.2 + 0.8 * height * np.clip(dist / 4.0, 0.2, 1.0), bits=16)
    save("jungle_presence.png", (dist > 1.0).astype(np.float32))
    t = fbm_heights(N, 6, 0.6, seed=43)[..., None]
    deep = np.array([0.18, 0.42, 0.12])
    lime = np.array([0.55, 0.75, 0.20])
    save("jungle_colour.png", deep * (1 - t) + lime * t)


def city() -> None:
    """City: a street grid (presence), density rising towards the centre, district partitions."""
    x = np.linspace(-1, 1, N)
    X, Z = np.meshgrid(x, x)
    block = 16  # pixels per block, 3-pixel streets
    streets = (np.arange(N) % block) < 3
    presence = ~(streets[None, :] | streets[:, None])
    avenue = np.abs(X + 0.15 * np.sin(3 * Z)) < 0.03  # a diagonal-ish avenue
    presence &= ~avenue
    save("city_presence.png", presence.astype(np.float32))
    r = np.sqrt(X**2 + Z**2)
    save("city_density.png", np.clip(1.0 - 0.8 * r, 0.15, 1.0))
    part = np.zeros((N, N, 3))
    part[r < 0.35] = (1, 0, 0)
    part[(r >= 0.35) & (r < 0.75)] = (0, 1, 0)
    part[r >= 0.75] = (0, 0, 1)
    save("city_partition.png", part)
    save("city_colour.png", np.stack([0.75 + 0.1 * X, 0.72 + 0.0 * X, 0.68 - 0.1 * Z], axis=2))


def meadow() -> None:
    """Close-up at a forest edge: a clearing with a wavy edge (presence 0) in the forest, and a colour map."""
    x = np.linspace(-1, 1, N)
    X, Z = np.meshgrid(x, x)
    angle = np.arctan2(Z, X)
    rng = np.random.default_rng(17)
    wobble = sum(
        a * np.sin(k * angle + p) for a, k, p in zip(rng.uniform(0.03, 0.08, 4), (2, 3, 5, 7), rng.random(4) * 6)
    )
    edge = 0.25 + wobble  # the clearing's radius (map units): about 150 m across on a 600 m terrain
    r = np.sqrt((X + 0.05) ** 2 + ((Z + 0.1) / 1.3) ** 2)
    save("meadow_presence.png", (r > edge).astype(np.float32))
    t = fbm_heights(N, 5, 0.55, seed=53)[..., None]
    save("meadow_colour.png", np.array([0.32, 0.5, 0.2]) * (1 - t) + np.array([0.5, 0.58, 0.22]) * t)


if __name__ == "__main__":
    main()
