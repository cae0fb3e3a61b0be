"""Small geometry helpers: SE(2) body poses, SE(3) homogeneous transforms, angles.

Frames (docs/DESIGN): `field` is the world (z up, ground z = 0); `body` has x forward, z up,
its origin at the operating height; body poses are SE(2) (x, y, yaw).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .config import Transform

FIELD_EXTENT_M = 10_000.0  # |x|, |y| of any field-frame position (m): beyond it, a unit error (lon/lat, mm)


def wrap_angle(a: float | np.ndarray) -> float | np.ndarray:
    """Wrap to [-π, π)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi if isinstance(a, np.ndarray) else (a + math.pi) % (2 * math.pi) - math.pi


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rotation for fixed-axis roll-pitch-yaw (URDF convention): R = Rz(yaw)·Ry(pitch)·Rx(roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def transform_matrix(t: Transform) -> np.ndarray:
    """4×4 homogeneous matrix of a config Transform."""
    m = np.eye(4)
    m[:3, :3] = rpy_matrix(*t.rpy)
    m[:3, 3] = t.xyz
    return m


def rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class SE2:
    """A body pose x_b: position (x, y) on the field and heading yaw (rad)."""

    x: float
    y: float
    yaw: float = 0.0

    @property
    def xy(self) -> np.ndarray:
        return np.array([self.x, self.y])

    def matrix(self, height: float = 0.0) -> np.ndarray:
        """4×4 pose of the body frame in the field frame, origin lifted to `height`."""
        m = np.eye(4)
        m[:3, :3] = rot_z(self.yaw)
        m[:3, 3] = (self.x, self.y, height)
        return m

    def to_local(self, p: np.ndarray) -> np.ndarray:
        """Field-frame xy point(s) → this pose's frame."""
        d = np.asarray(p, dtype=float) - self.xy
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)

    def to_field(self, p: np.ndarray) -> np.ndarray:
        """This pose's frame xy point(s) → field frame."""
        p = np.asarray(p, dtype=float)
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.stack([c * p[..., 0] - s * p[..., 1] + self.x, s * p[..., 0] + c * p[..., 1] + self.y], axis=-1)

    def distance(self, other: "SE2") -> float:
        return math.hypot(other.x - self.x, other.y - self.y)

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.yaw)


def yaw_quaternion_dot(yaw_a: float, yaw_b: float) -> float:
    """|q_a · q_b| for two pure-yaw rotations: |cos(Δyaw/2)| (used in the paper's d)."""
    return abs(math.cos((yaw_b - yaw_a) / 2.0))
