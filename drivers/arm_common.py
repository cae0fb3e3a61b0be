"""Pieces every Arm implementation shares: trajectory timing, IK with seeds, state assembly.

Shared so the CAN adapter and the bench simulator plan and solve identically: the executive
sees the same durations and the same IK answers on the bench and on the robot.
"""

from __future__ import annotations

import numpy as np

from capm_field.robot_model import RobotModel

from .interfaces import ArmState

SPEED_MARGIN = 0.95  # plan below the speed limit so the servo can always keep up
_SEEDS = (
    (0.0, 0.0, -0.005, 0.0, 0.0, 0.0),
    (0.0, 1.0, -1.0, 0.0, 0.0, 0.0),
    (0.0, 1.5, -1.5, 0.0, 0.8, 0.0),
    (0.0, 0.6, -1.8, 0.0, 1.2, 0.0),
)


class MinJerk:
    """Quintic (minimum-jerk) joint interpolation q0 -> q1, timed so no joint exceeds vmax."""

    PEAK = 1.875  # max of ds/dtau for s = 10t^3 - 15t^4 + 6t^5

    def __init__(self, q0: np.ndarray, q1: np.ndarray, vmax: float, min_duration: float = 0.0) -> None:
        self.q0 = np.asarray(q0, dtype=float).copy()
        self.dq = np.asarray(q1, dtype=float) - self.q0
        span = float(np.max(np.abs(self.dq))) if self.dq.size else 0.0
        self.duration = max(self.PEAK * span / (SPEED_MARGIN * vmax), min_duration)

    def __call__(self, t: float) -> np.ndarray:
        if self.duration <= 0.0:
            return self.q0 + self.dq
        tau = min(max(t / self.duration, 0.0), 1.0)
        s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau * tau)
        return self.q0 + s * self.dq


def within_limits(robot: RobotModel, q: np.ndarray) -> bool:
    return bool(np.all(q >= robot.lower - 1e-9) and np.all(q <= robot.upper + 1e-9))


def solve_ik(robot: RobotModel, frame: str, T_base: np.ndarray, q_seed: np.ndarray) -> np.ndarray | None:
    """Full-pose IK from the current joints first, then a few fixed seeds; None if none converges
    to a configuration that respects joint limits, the body keep-out and ground clearance."""
    if frame not in (robot.CAMERA, robot.NOZZLE):
        raise ValueError(f"frame must be 'camera' or 'nozzle', not {frame!r}")
    for seed in (np.asarray(q_seed, dtype=float), *map(np.array, _SEEDS)):
        q, ok, _ = robot.ik_pose(frame, T_base, seed)
        if ok and robot.config_valid(q):
            return q
    return None


def arm_state(robot: RobotModel, q: np.ndarray, moving: bool, stamp_ns: int, fault: str | None) -> ArmState:
    poses = robot.fk(q)
    return ArmState(
        joints=np.array(q, dtype=float),
        nozzle_pose=poses[robot.NOZZLE],
        camera_pose=poses[robot.CAMERA],
        moving=moving,
        stamp_ns=stamp_ns,
        fault=fault,
    )
