"""Wind: every tree's sway at a time, the same for every renderer and exporter.

A tree sways about its trunk base, towards the wind, by θᵢ(t) = A · sin(2π f t + φᵢ)
(:func:`sway_angles`), a rotation about the horizontal axis across the wind
(:func:`sway_rotation`); :func:`tree_matrices` composes it into each tree's
object→world matrix, which both renderers and the RIB, USD and Blender exports use.
"""

from __future__ import annotations

import numpy as np

from .instances import InstanceSet


def sway_angles(phase: np.ndarray, time_s: float, wind) -> np.ndarray:
    """Sway angle per tree, radians: θᵢ(t) = A · sin(2π f t + φᵢ).

    A = ``[wind] strength`` (degrees), f = ``frequency`` (Hz), φᵢ the tree's
    random phase (``InstanceSet.phase``), so neighbours do not move in lockstep.
    """
    if wind.strength <= 0:
        return np.zeros(len(phase))
    return np.radians(wind.strength) * np.sin(2.0 * np.pi * wind.frequency * time_s + phase.astype(np.float64))


def sway_rotation(theta: np.ndarray, direction_deg: float) -> np.ndarray:
    """(N, 3, 3) rotations tilting +Y towards the wind by θ (Rodrigues' formula).

    The wind blows towards w = (sin D, 0, cos D) (D clockwise from +Z, like the
    sun's azimuth); the axis is k = Y × w = (w_z, 0, −w_x) and
    R = I cos θ + sin θ [k]ₓ + (1 − cos θ) k kᵀ, which takes +Y to
    Y cos θ + w sin θ.
    """
    d = np.radians(direction_deg)
    k = np.array([np.cos(d), 0.0, -np.sin(d)])
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    c, s = np.cos(theta)[:, None, None], np.sin(theta)[:, None, None]
    return c * np.eye(3) + s * kx + (1.0 - c) * np.outer(k, k)


def tree_matrices(instances: InstanceSet, time_s: float, wind) -> np.ndarray:
    """Object→world (N, 4, 4): T(p) · R_sway(θ(t)) · R(q) · S(s); the sway pivots at the trunk base."""
    m = instances.matrices()
    if wind.strength > 0 and len(instances):
        r = sway_rotation(sway_angles(instances.phase, time_s, wind), wind.direction)
        m[:, :3, :3] = r @ m[:, :3, :3]
    return m
