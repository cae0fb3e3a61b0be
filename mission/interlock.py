"""Ignition interlock, independent of the planner: the flame may be on only while

  * the body is stationary (not moving, pose within `still_tol` of where the flame started),
  * the nozzle pose satisfies EPMC for the *detected* MPOI X̄_w: ‖X_e − X̄_w‖² ∈ [ε_min, ε_max]
    with the flame axis pointing at X̄_w (within `aim_tol` rad),
  * no fault is active (body, arm, igniter) and the arm is not moving,
  * the E-stop is released and the body is powered.

`check()` reads fresh driver states every call; the igniter adapter calls it before every
keep-alive (drivers/interfaces.py), so a violated condition stops the keep-alives and the board
extinguishes. Anything else the executive does first calls `extinguish()`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from capm_field.config import TaskConfig
from capm_field.robot_model import RobotModel
from drivers.interfaces import DriverSet


@dataclass
class InterlockStatus:
    ok: bool
    reasons: list[str]
    body_stationary: bool
    epmc_ok: bool
    estop: bool
    distance2: float = math.nan


@dataclass
class IgnitionInterlock:
    drivers: DriverSet
    robot: RobotModel
    task: TaskConfig
    mpoi_xy: tuple[float, float]
    still_tol: float = 0.01
    aim_tol: float = 0.05
    _anchor: tuple[float, float] | None = field(default=None, init=False)

    def anchor(self) -> None:
        """Remember where the body stands when ignition starts (stationarity reference)."""
        p = self.drivers.body.state().pose
        self._anchor = (p.x, p.y)

    def check(self) -> InterlockStatus:
        reasons: list[str] = []
        try:
            b = self.drivers.body.state()
            a = self.drivers.arm.state()
            g = self.drivers.igniter.state()
        except Exception as e:  # noqa: BLE001 - any driver error denies the permit
            return InterlockStatus(False, [f"state_unavailable:{type(e).__name__}"], False, False, True)
        stationary = not b.moving
        if self._anchor is not None and math.hypot(b.pose.x - self._anchor[0], b.pose.y - self._anchor[1]) > self.still_tol:
            stationary = False
        if not stationary:
            reasons.append("body_moving")
        if b.estop:
            reasons.append("estop")
        if not b.powered:
            reasons.append("body_unpowered")
        for name, f in (("body", b.fault), ("arm", a.fault), ("igniter", g.fault)):
            if f:
                reasons.append(f"{name}_fault:{f}")
        if a.moving:
            reasons.append("arm_moving")
        T = self.robot.T_field_base(b.pose) @ a.nozzle_pose
        X_e, axis = T[:3, 3], T[:3, 0]
        target = np.array([self.mpoi_xy[0], self.mpoi_xy[1], 0.0])
        d = target - X_e
        d2 = float(d @ d)
        aim = math.acos(max(-1.0, min(1.0, float(d @ axis) / max(math.sqrt(d2), 1e-9))))
        epmc = self.task.eps_min - 1e-9 <= d2 <= self.task.eps_max + 1e-9 and aim <= self.aim_tol
        if not epmc:
            reasons.append(f"epmc(d2={d2:.4f},aim={aim:.3f})")
        return InterlockStatus(not reasons, reasons, stationary, epmc, b.estop, d2)

    def permit(self) -> bool:
        return self.check().ok
