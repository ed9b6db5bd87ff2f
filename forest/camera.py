"""Camera paths: keyframes interpolated smoothly, frames and motion-blur sub-frames.

Positions and targets follow a centripetal Catmull–Rom spline through the keys
(Yuksel, Schaefer & Keyser 2011, "Parameterization and applications of
Catmull–Rom curves"): C¹, passes through every key, no cusps or overshoot
loops.  The field of view is interpolated linearly, or — between two keys that
both give a ``focal_length`` (an animated zoom, as a DCC keys it) — the focal
length is, and the fov follows from it on ``[camera] sensor_width``.  Frames
outside the keyed range hold the first or last key.

Depth of field (``[camera] f_stop``): a thin lens (Pharr, Jakob & Humphreys, *Physically Based
Rendering*, 4th ed., §5.2.3; Kolb, Mitchell & Hanrahan 1995) of focal length f (metres: the
``focal_length`` in mm / 1000, given or derived from the fov on ``sensor_width``) and f-number N has an
aperture of radius r = f / (2N).  It is focused at the distance z_f along the view axis: ``focus_distance``,
or the depth of ``focus_on`` (dot(focus_on − position, view axis), every frame), or |target − position|.
A point at depth z is then imaged as a disc (circle of confusion) of diameter
c = 2r·f·|z − z_f| / (z·(z_f − f)) on the sensor.  Keys may pull focus and aperture: where either of two
keys gives ``focus_distance`` (``f_stop``), the value is linear between the keys' values, a key without one
taking the camera's (for focus, its default evaluated at that key's pose).

A frame is rendered at time ``frame / fps`` seconds; with ``shutter`` = s > 0 a
frame averages sub-frames at ``frame + s·(k + ½)/K − s/2`` for k = 0 … K−1.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from .config import CameraConfig
from .config.schema import focal_length_from_fov, fov_from_focal_length


@dataclass(frozen=True)
class CameraState:
    """A camera pose: world position, look-at target and up vector (metres, Y up) and its horizontal fov in degrees."""

    position: np.ndarray  # (3,)
    target: np.ndarray  # (3,)
    up: np.ndarray  # (3,)
    fov: float  # degrees (horizontal... see forest.render: Mitsuba's fov_axis="x")
    f_stop: float | None = None  # f-number N; None: a pinhole
    focus_distance: float = 0.0  # metres along the view axis to the plane in focus (camera_at fills it)
    lens_radius: float = 0.0  # metres: f / (2N), 0 for a pinhole

    @property
    def depth_of_field(self) -> bool:
        """Whether this pose renders through a thin lens (an f-stop, so a lens radius > 0)."""
        return self.lens_radius > 0.0 and self.focus_distance > 0.0


def _catmull_rom(p0, p1, p2, p3, t, alpha=0.5):
    def tj(ti, a, b):
        return ti + max(np.linalg.norm(b - a), 1e-9) ** alpha

    t0 = 0.0
    t1 = tj(t0, p0, p1)
    t2 = tj(t1, p1, p2)
    t3 = tj(t2, p2, p3)
    u = t1 + (t2 - t1) * t
    a1 = (t1 - u) / (t1 - t0) * p0 + (u - t0) / (t1 - t0) * p1
    a2 = (t2 - u) / (t2 - t1) * p1 + (u - t1) / (t2 - t1) * p2
    a3 = (t3 - u) / (t3 - t2) * p2 + (u - t2) / (t3 - t2) * p3
    b1 = (t2 - u) / (t2 - t0) * a1 + (u - t0) / (t2 - t0) * a2
    b2 = (t3 - u) / (t3 - t1) * a2 + (u - t1) / (t3 - t1) * a3
    return (t2 - u) / (t2 - t1) * b1 + (u - t1) / (t2 - t1) * b2


def _default_focus(cam: CameraConfig, position: np.ndarray, target: np.ndarray) -> float:
    """z_f of a pose without a keyed focus: ``focus_distance``, the depth of ``focus_on``, or |target − position|."""
    if cam.focus_distance is not None:
        return float(cam.focus_distance)
    axis = target - position
    n = float(np.linalg.norm(axis))
    if cam.focus_on is not None:
        return float(np.dot(np.asarray(cam.focus_on, np.float64) - position, axis / max(n, 1e-12)))
    return n


def _with_lens(cam: CameraConfig, state: CameraState, f_stop: float | None, focus: float) -> CameraState:
    """``state`` with its thin lens: r = f / (2N), f = sensor_width / (2·tan(fov/2)) mm → metres."""
    if f_stop is None:
        return replace(state, focus_distance=focus)
    focal_m = focal_length_from_fov(state.fov, cam.sensor_width) / 1000.0
    return replace(state, f_stop=float(f_stop), focus_distance=float(focus), lens_radius=focal_m / (2.0 * f_stop))


def camera_at(cam: CameraConfig, frame: float) -> CameraState:
    """The camera at a (possibly fractional) frame, with its lens (:class:`CameraState`)."""
    state = _pose_at(cam, frame)
    keys = cam.keys
    if not keys or not any(k.focus_distance is not None or k.f_stop is not None for k in keys):
        return _with_lens(cam, state, cam.f_stop, _default_focus(cam, state.position, state.target))
    frames = [k.frame for k in keys]

    def key_focus(k) -> float:
        if k.focus_distance is not None:
            return float(k.focus_distance)
        return _default_focus(cam, np.asarray(k.position, np.float64), np.asarray(k.target, np.float64))

    def key_stop(k) -> float | None:
        return cam.f_stop if k.f_stop is None else float(k.f_stop)

    if len(keys) == 1 or frame <= frames[0] or frame >= frames[-1]:
        k = keys[0] if frame <= frames[0] else keys[-1]
        return _with_lens(cam, state, key_stop(k), key_focus(k))
    i = int(np.searchsorted(frames, frame, side="right") - 1)
    t = (frame - frames[i]) / (frames[i + 1] - frames[i])
    a, b = keys[i], keys[i + 1]
    focus = key_focus(a) + t * (key_focus(b) - key_focus(a))
    sa, sb = key_stop(a), key_stop(b)
    stop = None if sa is None or sb is None else sa + t * (sb - sa)
    return _with_lens(cam, state, stop, focus)


def _pose_at(cam: CameraConfig, frame: float) -> CameraState:
    """The pinhole pose (position, target, up, fov) at a frame."""
    up = np.asarray(cam.up, dtype=np.float64)
    keys = cam.keys
    if not keys:
        return CameraState(np.asarray(cam.position, float), np.asarray(cam.target, float), up, cam.fov)
    frames = np.array([k.frame for k in keys])
    P = np.array([k.position for k in keys], dtype=np.float64)
    T = np.array([k.target for k in keys], dtype=np.float64)
    F = np.array([k.fov for k in keys], dtype=np.float64)
    if len(keys) == 1 or frame <= frames[0]:
        return CameraState(P[0], T[0], up, float(F[0]))
    if frame >= frames[-1]:
        return CameraState(P[-1], T[-1], up, float(F[-1]))
    i = int(np.searchsorted(frames, frame, side="right") - 1)
    t = (frame - frames[i]) / (frames[i + 1] - frames[i])

    def spline(X):
        p1, p2 = X[i], X[i + 1]
        p0 = X[i - 1] if i > 0 else 2 * p1 - p2
        p3 = X[i + 2] if i + 2 < len(X) else 2 * p2 - p1
        return _catmull_rom(p0, p1, p2, p3, t)

    f0, f1 = keys[i].focal_length, keys[i + 1].focal_length
    if f0 is not None and f1 is not None:  # a zoom keyed in focal length moves linearly in focal length
        fov = fov_from_focal_length(f0 + t * (f1 - f0), cam.sensor_width)
    else:
        fov = float(F[i] + t * (F[i + 1] - F[i]))
    return CameraState(spline(P), spline(T), up, fov)


def subframe_times(frame: float, shutter: float, count: int) -> list[float]:
    """Times (in frames) averaged for motion blur: centred on ``frame``, spanning ``shutter``."""
    if shutter <= 0 or count <= 1:
        return [float(frame)]
    return [float(frame + shutter * ((k + 0.5) / count - 0.5)) for k in range(count)]


def look_at_matrix(position, target, up) -> np.ndarray:
    """Camera-to-world 4×4 (Mitsuba convention: camera looks along +Z, +Y up, +X left)."""
    p = np.asarray(position, float)
    d = np.asarray(target, float) - p
    d /= np.linalg.norm(d)
    u = np.asarray(up, float)
    left = np.cross(u, d)
    if np.linalg.norm(left) < 1e-9:  # looking straight up/down: pick another up
        left = np.cross([0.0, 0.0, 1.0], d)
    left /= np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, p
    return m


def frame_from_z(direction) -> np.ndarray:
    """A rotation (column-vector 4×4) whose local +Z axis is the unit ``direction``.

    Used to aim lights: the remaining axes come from crossing with +Y (or +X
    when ``direction`` is nearly vertical).
    """
    z = np.asarray(direction, float)
    z = z / np.linalg.norm(z)
    ref = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.99 else np.array([1.0, 0.0, 0.0])
    x = np.cross(ref, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = x, y, z
    return m


#: Height above the ground under which a camera counts as under it: a camera exactly on the surface, or a few
#: millimetres into it (float rounding of a painted or meshed terrain), still sees the scene.
UNDERGROUND = 0.01
#: Frames of a long shot checked against the ground at most (evenly spread, first and last included).
CLEARANCE_SAMPLES = 2000


def under_ground(cam: CameraConfig, height_at: Callable[[np.ndarray, np.ndarray], np.ndarray],
                 frames: Sequence[float]) -> str | None:  # fmt: skip
    """A warning when the camera is under the terrain at any of ``frames``, else None.

    ``height_at(x, z)`` is the terrain's height (:meth:`forest.terrain.Terrain.height_at`).  A camera
    under the ground sees it from beneath (black under a physical sky, or the ground's underside):
    renders still run, since an artist may want exactly that, but never without a word.
    """
    fs = np.asarray(sorted(set(float(f) for f in frames)), np.float64)
    if len(fs) > CLEARANCE_SAMPLES:
        fs = fs[np.unique(np.linspace(0, len(fs) - 1, CLEARANCE_SAMPLES).round().astype(np.int64))]
    pos = np.array([camera_at(cam, f).position for f in fs], np.float64).reshape(-1, 3)
    ground = np.asarray(height_at(pos[:, 0], pos[:, 2]), np.float64)
    depth = ground - pos[:, 1]
    under = depth > UNDERGROUND
    if not under.any():
        return None
    k = int(np.argmax(under))
    where = f"{depth[k]:.2f} m below the terrain (ground {ground[k]:.2f} m, camera {pos[k, 1]:.2f} m at x {pos[k, 0]:.1f}, z {pos[k, 2]:.1f})"
    what = ("[camera] keys" if cam.keys else "[camera] position") + " (or set [camera] height_above_ground)"
    if len(fs) == 1:
        return f"the camera is {where}: it sees the ground from beneath; raise {what}"
    return f"the camera is under the terrain at {int(under.sum())} of {len(fs)} frames checked, first at frame {fs[k]:g}, {where}: raise {what}"
