"""Driver interfaces: Body, Arm, Igniter, Camera — one contract for the robot and the bench.

Concurrency model (decided once, for every driver): **synchronous calls with timeouts**.
Every call that waits takes a `timeout` (s) and either returns a result or raises
`DriverTimeout`; `state()` never blocks and returns the latest cached state with its stamp.
Adapters run their own background threads for what must not depend on the caller (state
subscriptions, E-stop check-ins, CAN heartbeats and igniter keep-alives) and stop them in
`close()`. Drivers are context managers; `close()` is idempotent and must not hang.

Safety contract for the igniter: `ignite()` only *requests* a flame for a bounded duration; the
adapter sends keep-alives only while `permit()` returns True (the executive's interlock) and the
duration has not elapsed, and the igniter board extinguishes on its own when keep-alives stop.
Every error path of every adapter ends with `extinguish()` having been sent.

Moves take an optional `on_state` callback: called in the caller's thread with each new state
sample while the move runs (the executive logs the path the robot took from it). It must be
quick; an exception from it is logged once per move and otherwise ignored (a logging fault must
not leave a motion half done).

Times are integer nanoseconds (`time.monotonic_ns()` for stamps unless stated), SI units elsewhere.
"""

from __future__ import annotations

import abc
import logging
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from capm_field.camera import PinholeCamera
from capm_field.geometry import SE2


# ---- errors ----------------------------------------------------------------------------------
class DriverError(RuntimeError):
    """A driver could not do what was asked. `reason` is a short machine-readable tag."""

    reason = "driver_error"


class DriverTimeout(DriverError):
    reason = "timeout"


class LinkLost(DriverError):
    """The link to the robot side is gone (peer dead, frozen past its lease, bus-off)."""

    reason = "link_lost"


class EStopActive(DriverError):
    reason = "estop"


class MotionFailed(DriverError):
    """The motion could not be completed (blocked, slipped, out of reach, fault)."""

    reason = "motion_failed"


class LeaseRefused(DriverError):
    """Another commander holds the lease."""

    reason = "lease_refused"


class IgniterFault(DriverError):
    reason = "igniter_fault"


# ---- states ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class BodyState:
    pose: SE2
    moving: bool
    powered: bool
    estop: bool  # True while the E-stop is engaged (motion not allowed)
    stamp_ns: int
    odometry_m: float = 0.0  # distance travelled so far (energy meter input)
    fault: str | None = None


@dataclass(frozen=True)
class ArmState:
    joints: np.ndarray  # (6,) rad
    nozzle_pose: np.ndarray  # (4, 4) in the arm-base frame
    camera_pose: np.ndarray  # (4, 4) in the arm-base frame
    moving: bool
    stamp_ns: int
    fault: str | None = None


@dataclass(frozen=True)
class IgniterState:
    armed: bool
    flame_on: bool
    fuel: float  # remaining, 0..1
    stamp_ns: int
    fault: str | None = None  # latched until reset (e.g. "ignition_failed", "flame_out", "fuel_empty")


@dataclass(frozen=True)
class Frame:
    image: np.ndarray  # BGR uint8 (H, W, 3)
    stamp_ns: int
    intrinsics: PinholeCamera
    camera_pose_field: np.ndarray | None = None  # (4, 4) where known (bench), else None


@dataclass(frozen=True)
class MoveResult:
    ok: bool
    reason: str | None = None
    final: object | None = None  # SE2 for the body, joints for the arm
    extra: dict = field(default_factory=dict)


# ---- interfaces ------------------------------------------------------------------------------
StateCallback = Callable[[object], None]  # BodyState for the body, ArmState for the arm


class StateNotifier:
    """Calls a move's `on_state` with each state it is given; an exception from the callback is
    logged once (per notifier, i.e. per move) and otherwise ignored."""

    def __init__(self, on_state: StateCallback | None):
        self.on_state = on_state
        self._warned = False

    def __call__(self, state: object) -> None:
        if self.on_state is None:
            return
        try:
            self.on_state(state)
        except Exception:  # noqa: BLE001 - a logging fault must not break a motion
            if not self._warned:
                self._warned = True
                logging.getLogger(__name__).exception("on_state callback failed (ignored for the rest of this move)")


class _Closable(abc.ABC):
    def close(self) -> None:  # noqa: B027 - default: nothing to release
        """Release transports and stop background threads. Idempotent, never hangs."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Body(_Closable):
    """Spot body as a holonomic SE(2) platform at a fixed operating height."""

    @abc.abstractmethod
    def move_to(self, goal: SE2, timeout: float, on_state: StateCallback | None = None) -> MoveResult:
        """Walk to `goal` (field frame) and stop. Blocks until arrived, failed or timed out;
        `on_state` gets the body states seen on the way (see the module docstring)."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Stop walking now (does not raise)."""

    @abc.abstractmethod
    def state(self) -> BodyState: ...


class Arm(_Closable):
    """Unitree Z1: joint-space moves; poses are solved by the caller or the adapter's IK."""

    @abc.abstractmethod
    def move_joints(self, q: np.ndarray, timeout: float, on_state: StateCallback | None = None) -> MoveResult:
        """Move to joints `q`; `on_state` gets the arm states seen on the way."""

    @abc.abstractmethod
    def move_to_pose(self, frame: str, T_base: np.ndarray, timeout: float, on_state: StateCallback | None = None) -> MoveResult:
        """Move `frame` ('nozzle' | 'camera') to a pose in the arm-base frame (IK inside)."""

    @abc.abstractmethod
    def stow(self, timeout: float, on_state: StateCallback | None = None) -> MoveResult: ...

    @abc.abstractmethod
    def state(self) -> ArmState: ...

    def reset(self, timeout: float = 1.0) -> None:
        """Clear a latched arm fault (the arm stays disabled until the next move)."""
        raise DriverError(f"{type(self).__name__} cannot reset faults")


BOARD_KEEPALIVE_TIMEOUT_S = 0.08  # the board shuts the valve after a longer keep-alive gap (docs/protocols/can.md)


def credited_flame_s(flame_t0: float, now: float, last_keepalive: float) -> float:
    """Flame time an `ignite()` may count, from the flame's first confirmation at `flame_t0` to
    `now` (same clock), but not past the board's keep-alive timeout after the last keep-alive
    sent: a host that stalls (descheduled, swapping) sends none, the board shuts the valve on its
    own 80 ms later, and the host's first look after the stall must not count the stall as flame."""
    return max(0.0, min(now, last_keepalive + BOARD_KEEPALIVE_TIMEOUT_S) - flame_t0)


class Igniter(_Closable):
    """Flame igniter board behind the nozzle."""

    @abc.abstractmethod
    def arm(self, timeout: float) -> None: ...

    @abc.abstractmethod
    def disarm(self) -> None:
        """Disarm (extinguishes first). Does not raise."""

    @abc.abstractmethod
    def ignite(self, duration: float, permit: Callable[[], bool], timeout: float) -> MoveResult:
        """Light and hold the flame for `duration` s while `permit()` stays True.

        Blocks until the hold is complete (ok=True), the permit drops or a fault occurs
        (ok=False, reason). The flame is off when this returns, whatever the outcome.
        `extra['flame_s']` reports how long the flame was confirmed on, never counting past
        `BOARD_KEEPALIVE_TIMEOUT_S` after the last keep-alive sent (`credited_flame_s`).
        """

    @abc.abstractmethod
    def extinguish(self) -> None:
        """Flame off now. Never raises; safe to call at any time."""

    @abc.abstractmethod
    def state(self) -> IgniterState: ...

    def reset_fault(self, timeout: float = 1.0) -> None:
        """Clear a latched igniter fault (ignition failed, flame-out): an explicit, logged act."""
        raise DriverError(f"{type(self).__name__} cannot reset faults")


class Camera(_Closable):
    @abc.abstractmethod
    def capture(self, timeout: float) -> Frame: ...

    @property
    @abc.abstractmethod
    def intrinsics(self) -> PinholeCamera: ...


@dataclass
class DriverSet:
    """The four drivers a mission needs; closing it closes each (igniter first: flame off)."""

    body: Body
    arm: Arm
    igniter: Igniter
    camera: Camera
    extras: dict = field(default_factory=dict)

    def close(self) -> None:
        for d in (self.igniter, self.arm, self.body, self.camera):
            try:
                if d is self.igniter:
                    d.extinguish()
                d.close()
            except Exception:  # noqa: BLE001 - closing must go on for the others
                pass
        for x in self.extras.values():
            close = getattr(x, "close", None)
            if close:
                try:
                    close()
                except Exception:  # noqa: BLE001
                    pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
