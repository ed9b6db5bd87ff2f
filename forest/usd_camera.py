"""A camera read from a USD stage: ``[camera] usd = "shot.usda"`` (and ``usd_camera = "/World/cam"``).

:func:`read_usd_camera` turns a ``UsdGeom.Camera`` into what ``[camera]`` holds, so a shot's camera from
Maya, Houdini, Blender or forest's own USD export renders, exports and sets level of detail like a
camera written in the scene file.  The config's validation calls it (:class:`forest.config.schema.CameraConfig`).

**Which camera.**  The prim at ``usd_camera``; without it, the stage's only ``UsdGeom.Camera`` (none, or
several, is a mistake that names the cameras found).  Only perspective cameras are taken.

**Units and axes.**  Forest is Y up, metres (its own stages say ``upAxis = "Y"``, ``metersPerUnit = 1``).
A stage's points are scaled by its ``metersPerUnit`` — USD's fallback when a stage does not author it is
0.01, centimetres — and a Z-up stage is turned to Y up by (x, y, z) → (x, z, −y) (a rotation of −90° about
X, the inverse of a Y-up → Z-up export).  USD's lens attributes are read as millimetres (what every DCC
writes; only their ratio matters): ``focalLength`` and ``horizontalAperture`` become ``focal_length`` and
``sensor_width``, so the horizontal fov is 2·atan(horizontalAperture / (2·focalLength)).
``clippingRange`` (when authored) becomes ``near``/``far`` in metres, ``timeCodesPerSecond`` ``fps`` and
``shutterClose − shutterOpen`` ``shutter``, each unless the scene file gives it.  ``fStop`` (when authored
and > 0; USD's 0 means no depth of field) becomes ``f_stop``, unless the scene file gives it; the focus
distance needs no field of its own: the target sits at ``focusDistance`` (below), and forest focuses on the
target by default.  An animated ``fStop`` is read at its first sample.

**Pose.**  A USD camera looks down its local −Z with +Y up; its world transform (every ancestor's
transform composed) gives ``position``, the look direction and ``up``.  The ``target`` lies along the look
direction at ``focusDistance`` (when authored and positive; forest's export writes it) or
:data:`TARGET_DISTANCE` metres.  ``up`` is world +Y when the camera does not roll, else the camera's own up;
an animated camera whose roll changes over the shot cannot be followed by forest's one ``up``, which is
said as a :class:`~forest.errors.ForestWarning`.

**Animation.**  Every time sample of the camera's transform (its own and its ancestors' xformOps), of
``focalLength`` and of ``horizontalAperture`` becomes a key at frame = time code; forest interpolates between
keys (Catmull–Rom for the pose, linear focal length for the zoom).  A camera with one sample or none is a
still camera.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import ForestError, ForestWarning

#: ``[camera]`` fields a USD camera sets; giving one beside ``usd`` is refused.
USD_SETS = frozenset({"position", "target", "up", "fov", "focal_length", "sensor_width", "keys"})
#: Metres from the camera to its target along the look direction when the camera authors no focusDistance.
TARGET_DISTANCE = 100.0
#: Z up → Y up: (x, y, z) → (x, z, −y), a proper rotation (−90° about X).
Z_TO_Y = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: Radians of roll difference under which a constant ``up`` counts as following the camera.
ROLL_TOLERANCE = 1e-4
#: Stages read, by (path, mtime, size, prim): a config is validated more than once per run.
_CACHE: dict[tuple[Any, ...], UsdCamera] = {}


@dataclass(frozen=True)
class UsdCamera:
    """A USD camera in ``[camera]``'s terms: metres, Y up, lens in mm; ``keys`` as ``[[camera.keys]]`` tables."""

    path: str  # the camera prim's path
    position: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float]
    fov: float
    focal_length: float | None  # None when the aperture is animated (the keys then carry fov)
    sensor_width: float
    keys: tuple[dict[str, Any], ...] = ()
    near: float | None = None
    far: float | None = None
    fps: float | None = None
    shutter: float | None = None
    f_stop: float | None = None
    warnings: tuple[str, ...] = field(default=())


def read_usd_camera(path: str | Path, prim_path: str | None = None) -> UsdCamera:
    """The camera at ``prim_path`` of the USD stage ``path`` (or its only camera), in forest's units and axes.

    Raises :class:`~forest.errors.ForestError` with ``field`` ``usd`` or ``usd_camera`` (the ``[camera]``
    field to fix) and a one-line message for a stage that cannot be read, no camera, several cameras and
    no ``prim_path``, or a prim that is not a perspective camera.
    """
    p = Path(path)
    try:
        st = p.stat()
    except OSError as e:
        raise ForestError(f"cannot read the stage: {e.strerror}", field="usd") from None
    key = (str(p.resolve()), st.st_mtime_ns, st.st_size, prim_path)
    if key not in _CACHE:
        if len(_CACHE) >= 16:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = _read(p, prim_path)
    shot = _CACHE[key]
    for w in shot.warnings:
        warnings.warn(f"{p.name}: {w}", ForestWarning, stacklevel=2)
    return shot


def _open(path: Path):
    try:
        from pxr import Tf, Usd
    except ImportError:
        raise ForestError("reading a USD camera needs usd-core (pip install usd-core)", field="usd") from None
    try:
        stage = Usd.Stage.Open(str(path), Usd.Stage.LoadNone)
    except Tf.ErrorException as e:
        text = str(e).strip().splitlines()[-1].strip() if str(e).strip() else ""
        reason = (
            text.rsplit(" : ", 1)[-1].strip("'\" ") if " : " in text else text
        )  # the message, not USD's source line
        raise ForestError(f"cannot open as a USD stage ({reason or 'not a USD layer'})", field="usd") from None
    if stage is None:
        raise ForestError("cannot open as a USD stage", field="usd")
    return stage


def _find_camera(stage, prim_path: str | None):
    from pxr import Sdf, Tf, Usd, UsdGeom

    cameras = [p for p in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()) if p.IsA(UsdGeom.Camera)]
    names = ", ".join(str(c.GetPath()) for c in cameras[:5]) + (", …" if len(cameras) > 5 else "")
    if prim_path is None:
        if not cameras:
            unloaded = any(not q.IsLoaded() for q in stage.Traverse(Usd.PrimAllPrimsPredicate))
            hint = " loaded (one under a payload is read when usd_camera names it)" if unloaded else ""
            raise ForestError(f"the stage has no UsdGeom.Camera{hint}", field="usd")
        if len(cameras) > 1:
            raise ForestError(
                f"the stage has {len(cameras)} cameras ({names}); name one in usd_camera", field="usd_camera"
            )
        return cameras[0]
    if not Sdf.Path.IsValidPathString(prim_path) or not Sdf.Path(prim_path).IsAbsolutePath():
        raise ForestError(f"{prim_path!r} is not an absolute prim path (e.g. /World/cam)", field="usd_camera")
    try:  # a camera under a payload (the stage opens with none loaded: no geometry is read)
        stage.Load(Sdf.Path(prim_path))
    except Tf.ErrorException:
        pass  # nothing at or above that path to load: said below
    prim = stage.GetPrimAtPath(prim_path)
    others = f" (cameras on the stage: {names})" if cameras else " (the stage has no camera)"
    if not prim or not prim.IsDefined():
        raise ForestError(f"no prim at {prim_path}{others}", field="usd_camera")
    if not prim.IsA(UsdGeom.Camera):
        raise ForestError(
            f"{prim_path} is a {prim.GetTypeName() or 'typeless prim'}, not a camera{others}", field="usd_camera"
        )
    return prim


def _samples(prim) -> list[float]:
    """Time codes of every sample that moves or zooms the camera: its and its ancestors' xformOps, its lens."""
    from pxr import UsdGeom

    cam = UsdGeom.Camera(prim)
    times: set[float] = set()
    for attr in (cam.GetFocalLengthAttr(), cam.GetHorizontalApertureAttr()):
        times.update(attr.GetTimeSamples())
    p = prim
    while p and not p.IsPseudoRoot():
        xf = UsdGeom.Xformable(p)
        if xf:
            times.update(xf.GetTimeSamples())
            if xf.GetResetXformStack():
                break
        p = p.GetParent()
    return sorted(float(t) for t in times)


def _read(path: Path, prim_path: str | None) -> UsdCamera:
    from pxr import Usd, UsdGeom

    stage = _open(path)
    prim = _find_camera(stage, prim_path)
    where = str(prim.GetPath())
    cam = UsdGeom.Camera(prim)
    if cam.GetProjectionAttr().Get() == UsdGeom.Tokens.orthographic:
        raise ForestError(f"{where} is an orthographic camera; forest renders perspective cameras", field="usd_camera")
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    axes = Z_TO_Y if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z else np.eye(3)
    times = _samples(prim)
    codes = (
        [Usd.TimeCode(t) for t in times]
        if len(times) > 1
        else [Usd.TimeCode(times[0]) if times else Usd.TimeCode.Default()]
    )

    poses, lenses = [], []
    for tc in codes:
        m = np.array(cam.ComputeLocalToWorldTransform(tc), dtype=np.float64).T  # column vectors: p' = M·p
        position = axes @ m[:3, 3] * mpu
        forward = axes @ -m[:3, 2]
        up = axes @ m[:3, 1]
        if np.linalg.norm(forward) < 1e-12 or np.linalg.norm(up) < 1e-12:
            raise ForestError(f"{where}: its transform at time {_code(tc)} is degenerate", field="usd")
        forward /= np.linalg.norm(forward)
        up = up - forward * float(up @ forward)  # a sheared transform: keep up at right angles
        up /= np.linalg.norm(up)
        focus = cam.GetFocusDistanceAttr().Get(tc)
        distance = (
            float(focus) * mpu
            if focus is not None and cam.GetFocusDistanceAttr().HasAuthoredValue() and focus > 0
            else TARGET_DISTANCE
        )
        poses.append((position, position + forward * distance, forward, up))
        focal = float(cam.GetFocalLengthAttr().Get(tc))
        aperture = float(cam.GetHorizontalApertureAttr().Get(tc))
        if not (focal > 0 and aperture > 0 and math.isfinite(focal) and math.isfinite(aperture)):
            raise ForestError(
                f"{where}: focalLength {focal:g} and horizontalAperture {aperture:g} must be > 0", field="usd"
            )
        fov = math.degrees(2.0 * math.atan(aperture / (2.0 * focal)))
        if not 0.1 <= fov <= 179.0:
            raise ForestError(
                f"{where}: focalLength {focal:g} on horizontalAperture {aperture:g} gives a {fov:.4g}° field of view; "
                "forest takes 0.1–179°",
                field="usd",
            )
        lenses.append((focal, aperture, fov))

    world_up, note = _up(poses)
    fixed_aperture = len({a for _, a, _ in lenses}) == 1
    keys: list[dict[str, Any]] = []
    if len(codes) > 1:
        for tc, (pos, tgt, _, _), (focal, _aperture, fov) in zip(codes, poses, lenses):
            key: dict[str, Any] = {"frame": float(tc.GetValue()), "position": _t(pos), "target": _t(tgt)}
            key.update({"focal_length": focal} if fixed_aperture else {"fov": fov})
            keys.append(key)
    near = far = None
    clip = cam.GetClippingRangeAttr()
    if clip.HasAuthoredValue():
        rng = clip.Get(codes[0])
        if rng is not None and 0 < rng[0] < rng[1] and math.isfinite(rng[1]):
            near, far = float(rng[0]) * mpu, float(rng[1]) * mpu
    shutter = None
    open_, close = cam.GetShutterOpenAttr(), cam.GetShutterCloseAttr()
    if open_.HasAuthoredValue() or close.HasAuthoredValue():
        shutter = min(1.0, max(0.0, float(close.Get()) - float(open_.Get())))
    fps = float(stage.GetTimeCodesPerSecond()) if stage.HasAuthoredMetadata("timeCodesPerSecond") else None
    f_stop = None
    stop = cam.GetFStopAttr()
    if stop.HasAuthoredValue():
        value = stop.Get(codes[0])
        if value is not None and math.isfinite(float(value)) and float(value) > 0:
            f_stop = float(value)
    focal0, aperture0, fov0 = lenses[0]
    return UsdCamera(
        path=where,
        position=_t(poses[0][0]),
        target=_t(poses[0][1]),
        up=world_up,
        fov=fov0,
        focal_length=focal0 if fixed_aperture else None,
        sensor_width=aperture0,
        keys=tuple(keys),
        near=near,
        far=far,
        fps=fps if fps is not None and fps > 0 else None,
        shutter=shutter,
        f_stop=f_stop,
        warnings=(note,) if note else (),
    )


def _t(v: np.ndarray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def _code(tc) -> str:
    return "default" if tc.IsDefault() else f"{tc.GetValue():g}"


def _follows(up: np.ndarray, forward: np.ndarray, cam_up: np.ndarray) -> bool:
    """Whether a look-at with ``up`` reproduces the camera's own up (no roll between them)."""
    left = np.cross(up, forward)
    if np.linalg.norm(left) < 1e-9:
        return False
    made_up = np.cross(forward, left / np.linalg.norm(left))
    return float(made_up @ cam_up) > math.cos(ROLL_TOLERANCE)


def _up(
    poses: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
) -> tuple[tuple[float, float, float], str | None]:
    """One ``up`` for every pose: world +Y when the camera never rolls, else its first up (a note if it still rolls)."""
    for candidate in (np.array([0.0, 1.0, 0.0]), poses[0][3]):
        if all(_follows(candidate, f, u) for _, _, f, u in poses):
            return _t(candidate), None
    return _t(poses[0][3]), (
        "the camera's roll changes over the shot; forest's camera keeps one up vector (the first sample's), "
        "so the roll is not followed"
    )
