"""Blender export: a ``.blend`` whose trees are Geometry Nodes instances, ready to render in Cycles.

``forest export blender scene.toml -o scene.blend`` writes the scene's data
(species meshes, one point per tree, terrain, camera, lights, render settings)
to a temporary folder and runs Blender's own Python on it
(``blender -b --factory-startup --python blender_build.py``,
:mod:`forest.export.blender_build`), which builds the datablocks and saves the
file.  Blender 3.4 or newer is needed (Debian 12's ``blender`` package works);
it is found on ``PATH``, or named by ``$FOREST_BLENDER`` or ``blender=``.

**Axes.**  forest's world is Y up, Blender's Z up, both right-handed and in
metres: a point maps by the rotation

    C = [[1, 0, 0], [0, 0, −1], [0, 1, 0]]      (x, y, z) ↦ (x, −z, y),

a +90° turn about X (det C = 1: nothing is mirrored).  Species meshes are
converted to Blender's axes once (v ↦ C·v, n ↦ C·n), so a tree's matrix
becomes C·M·Cᵀ: position C·p, rotation C·R·Cᵀ, the same uniform scale.

**Instances.**  Geometry Nodes' Instance on Points takes a rotation as Euler
angles (XYZ order: R = R_z(γ)·R_y(β)·R_x(α)); :func:`euler_xyz` takes them
from each tree's C·R·Cᵀ, vectorised.  The species index picks the child of
the ``forest_species`` collection (children are ordered by name:
``species_<index>_<name>``).  Each species instances one level of detail:
``[export] blender_lod`` (default each species' first level).

**Look and light** (units in :mod:`forest.export.radiometry`): albedo =
base colour × texture × the tree's tint (an instance attribute) on tinted
parts, × the tree's bark factor (the instance attribute ``bark_tint``,
``[[species]] bark``'s hue/value jitter and moss; written only when some
tree's differs from 1) on bark parts, leaves
(1 − τ)·diffuse + τ·translucent under the cuticle's lobe (s·F̄·glossy + (1 − s·F̄)·leaf: a GGX gloss of the
recipe's ``leaf_roughness``, F̄(μ) its mean Fresnel reflectance, :func:`~forest.export.common.cuticle_fresnel`),
the texture's alpha cutting leaf cards; the
terrain textured by the ground's albedo grid (or ``terrain_colour``); a Sun lamp of
strength E (irradiance) turned so its −Z travels along −d; the World
background of strength L (a constant sky's radiance) or an environment map
turned +90° about Z so it lies as Mitsuba's ``envmap`` does (both map the
image's centre column to forest's +Z and its first quarter to +X); Cycles
with ``[render] spp``, ``max_depth`` − 1 bounces and the Standard view
transform, so the image compares with forest's sRGB PNG; ``[render] haze``
(aerial perspective) applied in the compositor from the depth pass.  UVs: Blender's v
runs up the image, the library's down, so v ↦ 1 − v.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..camera import camera_at, frame_from_z, look_at_matrix
from ..config import ConfigError
from ..config.schema import focal_length_from_fov
from ..errors import ForestError, ParameterError
from ..instances import quaternion_to_matrix
from ..lights import resolve_lights
from ..scene import Scene
from . import radiometry
from .common import (
    bark_factors,
    check_instances,
    cuticle_fresnel,
    export_frames,
    ground_colour,
    horizon,
    is_bark,
    leaf_cuticle,
    lod_mesh,
    look_instances,
    species_plans,
    split_water,
    terrain_texture,
)

#: forest (Y up) → Blender (Z up): (x, y, z) ↦ (x, −z, y).
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: The environment map's turn about Blender's Z that lays it as Mitsuba's ``envmap`` (module docstring).
ENVMAP_ROTATION_Z = 90.0
SCRIPT = Path(__file__).with_name("blender_build.py")


def haze_colour(config) -> tuple[float, float, float]:
    """The haze's colour for Cycles' constant-colour fog: ``[render] haze_colour``, else the constant sky's
    radiance, else a daylight blue (forest_path's own default, the sky's mean radiance, needs the sky model)."""
    hc = config.render.haze_colour
    if hc is not None:
        return (float(hc[0]), float(hc[1]), float(hc[2]))
    sky = resolve_lights(config).sky
    if sky is not None and sky.kind == "constant":
        r, g, b = (float(c) for c in sky.radiance)
        return (r, g, b)
    return (0.5, 0.6, 0.75)


@dataclass
class BlenderExport:
    """What :func:`export_blender` wrote and how long it took."""

    path: Path
    trees: int
    species: list[str] = field(default_factory=list)
    render: Path | None = None
    seconds: float = 0.0
    prepare_seconds: float = 0.0  # writing the data Blender reads
    blender_seconds: float = 0.0  # Blender building, saving (and rendering) the scene


def blender_error(output: str) -> str:
    """The line of Blender's output that says what went wrong (a Python exception, else its last error)."""
    lines = [l.strip() for l in output.splitlines() if l.strip()]
    for pattern in (r"^\w+(Error|Exception): ", r"^Error: (?!script failed)", r"[Ee]rror"):
        hits = [l for l in lines if re.search(pattern, l)]
        if hits:
            return hits[-1]
    return lines[-1] if lines else "no output"


def find_blender(explicit: str | Path | None = None) -> str:
    """The Blender executable: ``explicit``, ``$FOREST_BLENDER``, or ``blender`` on ``PATH``."""
    name = str(explicit or os.environ.get("FOREST_BLENDER") or "blender")
    found = shutil.which(name)
    if not found:
        raise ForestError(
            f"Blender not found ({name}): install Blender 3.4 or newer (Debian: apt-get install blender) "
            "or set FOREST_BLENDER to its executable"
        )
    return found


def to_blender_matrix(m: np.ndarray) -> np.ndarray:
    """A forest world-space 4×4 (object → world, column vectors) as Blender's: C4 · M, C4 = diag(C, 1)."""
    c = np.eye(4)
    c[:3, :3] = Y_UP_TO_Z_UP
    return c @ np.asarray(m, dtype=np.float64)


def euler_xyz(r: np.ndarray) -> np.ndarray:
    """Euler angles (α, β, γ) of rotations ``r`` (N, 3, 3) with R = R_z(γ)·R_y(β)·R_x(α) (Blender's XYZ).

    From R₂₀ = −sin β, R₂₁ = cos β sin α, R₂₂ = cos β cos α, R₁₀ = cos β sin γ,
    R₀₀ = cos β cos γ: β = atan2(−R₂₀, √(R₀₀² + R₁₀²)), α = atan2(R₂₁, R₂₂),
    γ = atan2(R₁₀, R₀₀); at gimbal lock (cos β ≈ 0) γ = 0 and
    α = atan2(−R₁₂, R₁₁).
    """
    r = np.asarray(r, dtype=np.float64)
    cy = np.hypot(r[:, 0, 0], r[:, 1, 0])
    beta = np.arctan2(-r[:, 2, 0], cy)
    locked = cy < 1e-9
    alpha = np.where(locked, np.arctan2(-r[:, 1, 2], r[:, 1, 1]), np.arctan2(r[:, 2, 1], r[:, 2, 2]))
    gamma = np.where(locked, 0.0, np.arctan2(r[:, 1, 0], r[:, 0, 0]))
    return np.stack([alpha, beta, gamma], axis=1)


def euler_to_matrix(e: np.ndarray) -> np.ndarray:
    """R = R_z(γ)·R_y(β)·R_x(α) for Euler angles (N, 3): the inverse of :func:`euler_xyz`."""
    a, b, g = (np.asarray(e, np.float64)[:, k] for k in range(3))
    ca, sa, cb, sb, cg, sg = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(g), np.sin(g)
    return np.stack(
        [
            np.stack([cg * cb, cg * sb * sa - sg * ca, cg * sb * ca + sg * sa], 1),
            np.stack([sg * cb, sg * sb * sa + cg * ca, sg * sb * ca - cg * sa], 1),
            np.stack([-sb, cb * sa, cb * ca], 1),
        ],
        1,
    )


def _save(folder: Path, name: str, a: np.ndarray, dtype: str) -> str:
    (folder / name).write_bytes(np.ascontiguousarray(a, dtype=dtype).tobytes())
    return name


def _mesh_files(folder: Path, stem: str, vertices, faces, normals, uv) -> dict:
    """A mesh in Blender's axes as raw arrays (positions, triangles, normals, per-vertex uv with v up)."""
    C = Y_UP_TO_Z_UP
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    return {
        "vertices": _save(folder, f"{stem}_v.bin", np.asarray(vertices, np.float64) @ C.T, "<f4"),
        "faces": _save(folder, f"{stem}_f.bin", np.asarray(faces, np.int64).ravel(), "<i4"),
        "normals": _save(folder, f"{stem}_n.bin", np.asarray(normals, np.float64) @ C.T, "<f4"),
        "uv": _save(folder, f"{stem}_uv.bin", np.stack([uv[:, 0], 1.0 - uv[:, 1]], 1), "<f4"),
    }


def rgba(rgb: np.ndarray) -> np.ndarray:
    """Per-point colours (N, 3) as Blender's colour attributes hold them: (N, 4) float64 with A = 1."""
    rgb = np.asarray(rgb, np.float64).reshape(-1, 3)
    return np.concatenate([rgb, np.ones((len(rgb), 1))], axis=1)


def _lod_choice(scene: Scene, plans) -> dict[int, object]:
    config = scene.config
    want = config.export.blender_lod
    out = {}
    for plan in plans:
        names = [l.name for l in plan.species.lods]
        name = want or names[0]
        if name not in names:
            raise ConfigError(
                config.path,
                "export.blender_lod",
                f"{name!r} is not a level of {plan.model!r} (levels: {', '.join(names)})",
            )
        out[plan.index] = plan.species.lods[names.index(name)]
    return out


def write_manifest(scene: Scene, folder: Path, frames: list[int]) -> dict:
    """Write the scene's data for :mod:`forest.export.blender_build` into ``folder``; returns the manifest.

    With bark factors (:func:`forest.export.common.bark_factors`) the points
    get ``bark_tint`` (``points_bark_tint.bin``: RGBA, A = 1, as ``tint``) and
    every bark part ``"bark": true``, which multiplies its material by it;
    without, neither is written and the manifest is that of unvarying bark.
    """
    config, instances = scene.config, look_instances(scene)
    bark = bark_factors(scene)
    C = Y_UP_TO_Z_UP
    plans = species_plans(scene, used_only=False)
    lods = _lod_choice(scene, plans)
    species = []
    for plan in plans:
        parts = []
        for k, (part, m) in enumerate(lod_mesh(lods[plan.index])):
            if len(m.faces) == 0:
                continue
            entry = _mesh_files(folder, f"s{plan.index}_p{k}", m.vertices, m.faces, m.normals, m.uv)
            tex = getattr(part, "texture", None)
            entry.update(
                kind=str(getattr(part, "kind", "surface")),
                colour=[float(c) for c in part.colour],
                tinted=bool(getattr(part, "tinted", False)),
                translucency=float(getattr(part, "translucency", 0.0) or 0.0),
                texture=str(Path(tex).resolve()) if tex else None,
                alpha=bool(tex),
            )
            if bark is not None and is_bark(part):
                entry["bark"] = True
            sheen, alpha = leaf_cuticle(part)
            if sheen > 0:
                entry.update(sheen=sheen, sheen_roughness=alpha, sheen_fresnel=cuticle_fresnel(alpha))
            parts.append(entry)
        species.append(
            {"name": plan.name, "object": f"species_{plan.index:03d}_{plan.name}", "model": plan.model, "parts": parts}
        )
    # trees: position C·p, rotation C·R·Cᵀ as Euler XYZ, uniform scale, species, tint (and bark factor)
    n = len(instances)
    R = quaternion_to_matrix(instances.rotation.astype(np.float64)) if n else np.zeros((0, 3, 3))
    rot = euler_xyz(C @ R @ C.T) if n else np.zeros((0, 3))
    points = {
        "count": n,
        "position": _save(folder, "points_p.bin", instances.position.astype(np.float64) @ C.T, "<f4"),
        "rotation": _save(folder, "points_r.bin", rot, "<f4"),
        "scale": _save(folder, "points_s.bin", instances.scale, "<f4"),
        "species": _save(folder, "points_species.bin", instances.species, "<i4"),
        "tint": _save(folder, "points_tint.bin", rgba(instances.tint), "<f4"),
    }
    if bark is not None:
        points["bark_tint"] = _save(folder, "points_bark_tint.bin", rgba(bark), "<f4")
    ground, water = split_water(scene)
    t = _mesh_files(folder, "terrain", ground.vertices, ground.faces, ground.normals, ground.uv)
    t["colour"] = list(ground_colour(scene))
    grid = terrain_texture(scene)
    if grid is not None:
        from ..images import write_image

        write_image(folder / "terrain.png", grid)
        t.update(texture=str((folder / "terrain.png").resolve()), colour=[1.0, 1.0, 1.0])
    far = horizon(scene)
    h = None
    if far is not None:  # the hills past the terrain's edge, in their far colour
        h = _mesh_files(folder, "horizon", far.vertices, far.faces, far.normals, far.uv)
        h["colour"] = list(far.colour)
    w = None
    if water is not None:  # the ground's water, apart from the terrain: Fresnel-weighted gloss over its colour
        w = _mesh_files(folder, "water", water.vertices, water.faces, water.normals, water.uv)
        w.update(colour=list(water.colour), roughness=water.roughness, ior=water.ior)
    keys = []
    # A lens given in millimetres goes over as one (sensor_width + lens), else as the angle.
    lens = config.camera.focal_length is not None or any(k.focal_length is not None for k in config.camera.keys)
    lens = lens or config.camera.f_stop is not None  # depth of field: Blender's lens radius is lens / (2·f-stop)
    for f in frames:
        s = camera_at(config.camera, f)
        m = to_blender_matrix(look_at_matrix(s.position, s.target, s.up) @ np.diag([-1.0, 1.0, -1.0, 1.0]))
        keys.append({"frame": int(f), "matrix": [float(x) for x in m.ravel()], "fov": float(s.fov)})
        if lens:
            keys[-1]["lens"] = focal_length_from_fov(float(s.fov), float(config.camera.sensor_width))
        if s.depth_of_field:  # Cycles' thin lens: f-stop, focus distance along the view axis (metres)
            keys[-1]["dof"] = {"f_stop": float(s.f_stop or 0.0), "focus_distance": float(s.focus_distance or 0.0)}
    camera = {"near": float(config.camera.near), "far": float(config.camera.far), "keys": keys}
    if lens:
        camera["sensor_width"] = float(config.camera.sensor_width)
    lights = scene.lights
    sun = None
    if lights.sun is not None:
        m = to_blender_matrix(frame_from_z(lights.sun.direction))  # local +Z towards the sun
        sun = {
            "strength": radiometry.blender_sun_strength(lights.sun.irradiance),
            "colour": [float(c) for c in lights.sun.colour],
            "angle": radiometry.SUN_ANGLE_DEG,
            "matrix": [float(x) for x in m.ravel()],
        }
    sky: dict | None = None
    sky_light = lights.sky
    if sky_light is not None:
        strength, colour = sky_light.dome()
        if sky_light.kind == "envmap":
            assert sky_light.envmap is not None  # the schema requires it for this kind
            sky = {
                "strength": strength,
                "envmap": str(Path(sky_light.envmap).resolve()),
                "rotation_z": ENVMAP_ROTATION_Z,
            }
        else:  # a constant sky, or the neutral blue dome a physical sun-sky is written as
            sky = {"strength": strength, "colour": [float(c) for c in colour]}
    r = config.render
    manifest = {
        "format": 1,
        "species": species,
        "points": points,
        "terrain": t,
        "horizon": h,
        "water": w,
        "camera": camera,
        "sun": sun,
        "sky": sky,
        "render": {
            "width": r.width,
            "height": r.height,
            "spp": r.spp,
            "max_depth": r.max_depth,
            "seed": r.seed,
            "fps": float(config.camera.fps),
            "haze": float(r.haze),
            "haze_colour": [float(c) for c in haze_colour(config)],
            "frame_start": int(frames[0]),
            "frame_end": int(frames[-1]),
        },
    }
    (folder / "manifest.json").write_text(json.dumps(manifest, indent=1, sort_keys=True))
    return manifest


def export_blender(
    scene: Scene,
    path: str | Path,
    *,
    blender: str | Path | None = None,
    frames: str | list[int] | None = None,
    render: str | Path | None = None,
    coverage: bool = False,
    timeout: float | None = None,
    progress=None,
) -> BlenderExport:
    """Write ``path`` (a ``.blend``) with the scene built in Blender (see the module docstring).

    ``render``: also render the scene to this PNG (Cycles, the scene's
    settings); with ``coverage`` the terrain is held out and the sky
    transparent, so the PNG's alpha marks the trees.  ``frames``: the camera's
    keyed frames (default its keyed range, or frame 1).
    """
    t0 = time.perf_counter()
    path = Path(path)
    if path.suffix.lower() != ".blend":
        raise ParameterError("output", f"{path}: a Blender file name must end in .blend")
    if path.is_dir():
        raise ParameterError("output", f"{path}: is a folder; give the .blend file's name")
    exe = find_blender(blender)
    check_instances(scene.config, scene.instances)
    frame_list = export_frames(scene.config, frames)
    report = progress or (lambda _f, _m="": None)
    result = BlenderExport(path=path, trees=len(scene.instances))
    with tempfile.TemporaryDirectory(prefix="forest-blender-") as tmp_name:
        folder = Path(tmp_name)
        manifest = write_manifest(scene, folder, frame_list)
        result.species = [s["name"] for s in manifest["species"]]
        result.prepare_seconds = time.perf_counter() - t0
        report(0.3, "blender")
        t1 = time.perf_counter()
        with atomic_path(path) as out:
            out.unlink()  # Blender writes the file itself; an existing one would get a .blend1 backup beside it
            cmd = [exe, "-b", "--factory-startup", "--python-exit-code", "3", "--python", str(SCRIPT), "--"]
            cmd += [str(folder / "manifest.json"), str(out)]
            if render is not None:
                cmd += ["--render", str(Path(render).resolve())] + (["--coverage"] if coverage else [])
            try:
                proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
            except subprocess.TimeoutExpired:
                raise ForestError(f"{path}: Blender did not finish in {timeout:g} s") from None
            if proc.returncode != 0 or not out.is_file():
                raise ForestError(f"{path}: Blender failed: {blender_error(proc.stdout + proc.stderr)}")
        result.blender_seconds = time.perf_counter() - t1
    if render is not None:
        result.render = Path(render)
    report(1.0, "done")
    result.seconds = time.perf_counter() - t0
    return result
