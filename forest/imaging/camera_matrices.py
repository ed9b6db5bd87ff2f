"""The camera of a frame as OpenEXR's ``worldToCamera`` and ``worldToNDC`` header matrices.

OpenEXR's standard attributes (``ImfStandardAttributes.h``) define:

- **camera space** — RenderMan's: left-handed, origin at the camera, +x right
  and +y up in the image, +z along the viewing direction (points in front of
  the camera have z > 0);
- **NDC** — the image plane, (0, 0) at the upper-left and (1, 1) at the
  lower-right corner of the display window, +x right, +y down; a world point
  maps to NDC by multiplying it by ``worldToNDC`` (with the homogeneous divide)
  and dropping z.

forest's cameras follow Mitsuba (:func:`forest.camera.look_at_matrix`: +Z
forward, +Y up, +X *left*), so ``worldToCamera = diag(−1, 1, 1, 1) · look_at⁻¹``.
The perspective projection with horizontal field of view ``fov`` (Mitsuba's
``fov_axis = "x"``), ``tx = tan(fov/2)`` and ``ty = tx · height/width`` is::

    X = x / (2 tx) + z/2          u = X / W = ½ + x / (2 tx z)
    Y = −y / (2 ty) + z/2         v = Y / W = ½ − y / (2 ty z)
    Z = f (z − n) / (f − n)       Z / W = 0 at the near plane, 1 at the far plane
    W = z

The matrices here are in the column-vector convention (``p' = M @ p``);
:meth:`CameraMatrices.header` writes their transposes, because Imath (and so
OpenEXR, Nuke, OpenImageIO) multiplies row vectors (``p' = p · M``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import look_at_matrix

FLIP_X = np.diag([-1.0, 1.0, 1.0, 1.0])
"""Mitsuba camera space (+X left) → OpenEXR / RenderMan camera space (+x right)."""


@dataclass(frozen=True)
class CameraMatrices:
    """``world_to_camera`` and ``world_to_ndc``: 4×4 float64, column-vector convention."""

    world_to_camera: np.ndarray
    world_to_ndc: np.ndarray

    def header(self) -> dict[str, np.ndarray]:
        """The OpenEXR header attributes (``worldToCamera``, ``worldToNDC``), transposed to Imath's row vectors."""
        return {
            "worldToCamera": np.ascontiguousarray(self.world_to_camera.T),
            "worldToNDC": np.ascontiguousarray(self.world_to_ndc.T),
        }

    def project(self, points: np.ndarray) -> np.ndarray:
        """World points ``(N, 3)`` → NDC ``(N, 3)``: u, v and the [0, 1] depth between near and far."""
        p = np.asarray(points, dtype=np.float64)
        h = np.concatenate([p, np.ones((len(p), 1))], axis=1) @ self.world_to_ndc.T
        return h[:, :3] / h[:, 3:4]


def projection(fov: float, width: int, height: int, near: float, far: float) -> np.ndarray:
    """OpenEXR camera space → homogeneous NDC for a horizontal ``fov`` in degrees (see the module docstring)."""
    if not 0.0 < fov < 180.0:
        raise ValueError(f"fov must be in (0, 180) degrees, got {fov}")
    if not 0.0 < near < far:
        raise ValueError(f"need 0 < near < far, got {near}, {far}")
    tx = np.tan(np.radians(fov) / 2.0)
    ty = tx * height / width
    return np.array(
        [
            [0.5 / tx, 0.0, 0.5, 0.0],
            [0.0, -0.5 / ty, 0.5, 0.0],
            [0.0, 0.0, far / (far - near), -far * near / (far - near)],
            [0.0, 0.0, 1.0, 0.0],
        ]
    )


def camera_matrices(
    position,
    target,
    up,
    fov: float,
    width: int,
    height: int,
    *,
    near: float = 0.5,
    far: float = 100000.0,
) -> CameraMatrices:
    """The header matrices of a perspective camera at ``position`` looking at ``target``.

    ``fov`` is horizontal, in degrees, as in ``[camera]``; ``near``/``far`` as
    the renderer's clip planes.  Takes a :class:`forest.camera.CameraState`'s
    fields: ``camera_matrices(s.position, s.target, s.up, s.fov, w, h, ...)``.
    """
    cam_to_world = look_at_matrix(position, target, up)
    world_to_camera = FLIP_X @ np.linalg.inv(cam_to_world)
    return CameraMatrices(
        world_to_camera=world_to_camera,
        world_to_ndc=projection(fov, width, height, near, far) @ world_to_camera,
    )
