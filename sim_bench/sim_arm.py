"""Simulated Unitree Z1 arm: the gateway's controller model and an in-process `Arm` driver.

`ArmPlant` is the arm as the CAN gateway presents it (modes, latched faults, target checks,
speed-limited joint servo, pinocchio kinematics through `RobotModel`). The wire-level gateway
(`sim_bench.can_robot_side`) and the in-process `SimArmDriver` both drive this one class, so
the two bench paths behave alike. Time is passed in; the plant never reads a clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capm_field.robot_model import RobotModel
from drivers.arm_common import MinJerk, arm_state, solve_ik, within_limits
from drivers.interfaces import (
    Arm,
    ArmState,
    DriverTimeout,
    LinkLost,
    MoveResult,
    StateCallback,
    StateNotifier,
)

from .sim_clock import SimClock

DISABLED, HOLDING, TRACKING, STOWING, FAULT = "disabled", "holding", "tracking", "stowing", "fault"


@dataclass
class ArmFaultHooks:
    """Fault injection (a later fault-injection issue drives these)."""

    fail_ik: bool = False  # in-process driver: IK reports no solution
    link_lost: bool = False  # in-process driver: the link is gone (LinkLost)


class ArmPlant:
    def __init__(
        self,
        robot: RobotModel,
        q0: np.ndarray | None = None,
        max_speed: float | None = None,
        jump_window: float = 0.02,
        tol: float = 1e-3,
    ) -> None:
        self.robot = robot
        self.stow_q = np.array(robot.cfg.arm.stow_joints, dtype=float)
        self.vmax = float(max_speed if max_speed is not None else robot.cfg.arm.max_joint_speed)
        # a new target may differ from the last one by at most what vmax covers in jump_window
        self.max_step = self.vmax * jump_window
        self.tol = tol
        self.q = np.array(self.stow_q if q0 is None else q0, dtype=float)
        self.ref = self.q.copy()
        self.mode = DISABLED
        self.fault: str | None = None
        self.fault_persists = False  # a fault RESET does not clear (a broken joint, a motor that keeps tripping)
        self.moving = False
        self.targets_applied = 0
        # fault hook: (n, code) -> latch `code` once n more targets have been applied (mid-move)
        self.fault_after_targets: tuple[int, str] | None = None

    # ---- commands --------------------------------------------------------------------------
    def enable(self) -> None:
        if self.mode == DISABLED:
            self.ref = self.q.copy()
            self.mode = HOLDING

    def disable(self) -> None:
        if self.mode != FAULT:
            self.ref = self.q.copy()
            self.mode = DISABLED

    def stop(self) -> None:
        self.ref = self.q.copy()
        if self.mode in (TRACKING, STOWING):
            self.mode = HOLDING

    def stow(self) -> None:
        if self.mode in (HOLDING, TRACKING):
            self.ref = self.q.copy()
            self.mode = STOWING

    def reset(self) -> None:
        if self.mode == FAULT and not self.fault_persists:
            self.fault = None
            self.ref = self.q.copy()
            self.mode = DISABLED

    def set_fault(self, code: str, persist: bool = False) -> None:
        """Latched fault: the arm holds where it is until RESET (then ENABLE); with `persist`,
        RESET does not clear it."""
        self.fault = code
        self.fault_persists = persist
        self.mode = FAULT
        self.ref = self.q.copy()

    def set_target(self, q: np.ndarray) -> bool:
        """One streamed joint target. Out-of-range or jumping targets fault the arm (never clamped)."""
        if self.mode not in (HOLDING, TRACKING):
            return False
        q = np.asarray(q, dtype=float)
        if np.any(q < self.robot.lower - 1e-3) or np.any(q > self.robot.upper + 1e-3):  # 1e-3: wire quantisation
            self.set_fault("target_out_of_range")
            return False
        if np.max(np.abs(q - self.ref)) > self.max_step:
            self.set_fault("target_jump")
            return False
        self.ref = np.clip(q, self.robot.lower, self.robot.upper)
        self.mode = TRACKING
        self.targets_applied += 1
        if self.fault_after_targets is not None:
            n, code = self.fault_after_targets
            self.fault_after_targets = (n - 1, code) if n > 1 else None
            if n <= 1:
                self.set_fault(code)
        return True

    # ---- dynamics --------------------------------------------------------------------------
    def step(self, dt: float) -> None:
        if self.mode == STOWING:
            self.ref = self.stow_q.copy()
        if self.mode in (TRACKING, STOWING, HOLDING):
            err = self.ref - self.q
            dq = np.clip(err, -self.vmax * dt, self.vmax * dt)
            self.q = self.q + dq
            self.moving = bool(np.max(np.abs(dq)) > 1e-7)
            if self.mode == STOWING and np.max(np.abs(self.stow_q - self.q)) < 1e-9:
                self.mode = HOLDING
        else:
            self.moving = False

    @property
    def enabled(self) -> bool:
        return self.mode in (HOLDING, TRACKING, STOWING)

    @property
    def stowed(self) -> bool:
        return bool(np.max(np.abs(self.q - self.stow_q)) < self.tol)


NOTIFY_PERIOD_S = 0.02  # simulated seconds between on_state calls during a move (the sim body's step)


class SimArmDriver(Arm):
    """In-process Z1 on a simulated clock: same contract as `CanArm`, no bus, deterministic."""

    def __init__(
        self,
        robot: RobotModel | None = None,
        clock: SimClock | None = None,
        dt: float = 0.002,
        at_target_tol: float = 2e-3,
        plant: ArmPlant | None = None,
    ) -> None:
        self.robot = robot or RobotModel()
        self.clock = clock or SimClock()
        self.dt = dt
        self._ticks = 0
        self.tol = at_target_tol
        self.plant = plant or ArmPlant(self.robot)
        self.hooks = ArmFaultHooks()
        self._closed = False

    # ---- helpers ---------------------------------------------------------------------------
    def _check_link(self) -> None:
        if self._closed:
            raise LinkLost("adapter closed")
        if self.hooks.link_lost:
            self.plant.stop()
            raise LinkLost("simulated link loss")

    def _tick(self, notify: StateNotifier | None = None) -> None:
        self.plant.step(self.dt)
        self.clock.sleep(self.dt)
        self._ticks += 1
        # on_state every NOTIFY_PERIOD_S, not every 2 ms step: each state costs two
        # forward-kinematics solves (every step: +80 % wall time of the bench mission)
        if notify is not None and self._ticks % max(1, round(NOTIFY_PERIOD_S / self.dt)) == 0:
            notify(self.state())

    def _fail(self, reason: str) -> MoveResult:
        self.plant.stop()
        return MoveResult(False, reason, final=self.plant.q.copy())

    def reset(self, timeout: float = 1.0) -> None:
        """Clear a latched arm fault (the arm is disabled afterwards; moves re-enable it)."""
        self._check_link()
        self.plant.reset()

    # ---- Arm -------------------------------------------------------------------------------
    def move_joints(self, q: np.ndarray, timeout: float, on_state: StateCallback | None = None) -> MoveResult:
        self._check_link()
        notify = StateNotifier(on_state)
        q = np.asarray(q, dtype=float).reshape(6)
        if not np.all(np.isfinite(q)) or not within_limits(self.robot, q):
            return MoveResult(False, "joint_limit", final=self.plant.q.copy())
        if self.plant.fault:
            return MoveResult(False, self.plant.fault, final=self.plant.q.copy())
        t_end = self.clock.now() + timeout
        self.plant.enable()
        traj = MinJerk(self.plant.q, q, self.plant.vmax)
        t = 0.0
        while True:
            self._check_link()
            if self.plant.fault:
                return self._fail(self.plant.fault)
            if self.clock.now() >= t_end:
                self.plant.stop()
                raise DriverTimeout(f"arm move not finished within {timeout:.3f} s")
            t += self.dt
            if t - self.dt < traj.duration:
                self.plant.set_target(traj(t))
                if self.plant.fault:
                    return self._fail(self.plant.fault)
            elif np.max(np.abs(self.plant.q - q)) < self.tol:
                self._tick(notify)  # one more state sample, as on the wire
                return MoveResult(True, final=self.plant.q.copy(), extra={"duration_s": traj.duration})
            self._tick(notify)

    def move_to_pose(self, frame: str, T_base: np.ndarray, timeout: float, on_state: StateCallback | None = None) -> MoveResult:
        self._check_link()
        sol = None if self.hooks.fail_ik else solve_ik(self.robot, frame, T_base, self.plant.q)
        if sol is None:
            return MoveResult(False, "ik_failed", final=self.plant.q.copy())
        return self.move_joints(sol, timeout, on_state)

    def stow(self, timeout: float, on_state: StateCallback | None = None) -> MoveResult:
        self._check_link()
        notify = StateNotifier(on_state)
        if self.plant.fault:
            return MoveResult(False, self.plant.fault, final=self.plant.q.copy())
        t_end = self.clock.now() + timeout
        self.plant.enable()
        self.plant.stow()
        while not (self.plant.stowed and self.plant.mode == HOLDING):
            self._check_link()
            if self.plant.fault:
                return self._fail(self.plant.fault)
            if self.clock.now() >= t_end:
                self.plant.stop()
                raise DriverTimeout(f"stow not finished within {timeout:.3f} s")
            self._tick(notify)
        return MoveResult(True, final=self.plant.q.copy())

    def state(self) -> ArmState:
        fault = "link_lost" if self.hooks.link_lost else self.plant.fault
        return arm_state(self.robot, self.plant.q, self.plant.moving, self.clock.now_ns(), fault)

    def close(self) -> None:
        if not self._closed:
            self.plant.stop()
            self._closed = True
