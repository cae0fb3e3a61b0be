"""`CanArm`: the Unitree Z1 behind its CAN gateway (protocol: docs/protocols/can.md).

Moves stream joint targets at 500 Hz (minimum-jerk from the measured joints, timed within the
joint speed limit) as ARM_TARGET_A/B pairs; the gateway servoes to them and reports joint
state (100 Hz) and status (20 Hz + on change). `move_to_pose` solves IK with RobotModel first.
A state set is the ARM_STATE_A frame directly followed (within PAIR_WINDOW_S = 30 ms, nothing
of the pair's ids in between) by the ARM_STATE_B with the same counter (`SetPairer`); other
halves are discarded.
Outcomes: MoveResult(ok=False, reason) for motion failures (joint_limit, ik_failed, gateway
fault codes), DriverTimeout when `timeout` runs out, LinkLost when the gateway heartbeat stops
(or the bus fails); every failure path sends STOP (best effort) before returning or raising.
`close()` sends STOP as the host's last word: no target or command of another thread follows it.
Start-up: the constructor synchronises the ARM_CMD counter with NOPs (`sync_counter`, can.md
"Host start-up"), so after a host restart the gateway accepts the first command (RESET_FAULT of
the HOST_LOST it latched, ENABLE). The target stream needs no sync frames: its first set after a
restart may be discarded (counter rule) and the stream goes on with the next.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from capm_field.robot_model import RobotModel

from .arm_common import MinJerk, arm_state, solve_ik, within_limits
from .can.codec import (
    ARM_ENABLE,
    ARM_FAULTS,
    ARM_MODES,
    ARM_RESET,
    ARM_STOP,
    ARM_STOW,
    NODE_HOST_ARM,
    SetPairer,
    database,
)
from .can.config import CanArmConfig
from .can.link import CanLink, sync_counter, wait_for
from .interfaces import (
    Arm,
    ArmState,
    DriverTimeout,
    LinkLost,
    MoveResult,
    StateCallback,
    StateNotifier,
)


ON_STATE_PERIOD_NS = 10_000_000  # on_state of a move: at most every 10 ms of state stamps


@dataclass
class StreamStats:
    sent: int = 0  # target pairs sent
    overruns: int = 0  # ticks more than 5 periods late (skipped, not burst)
    duration_s: float = 0.0

    @property
    def rate_hz(self) -> float:
        return self.sent / self.duration_s if self.duration_s > 0 else 0.0


class CanArm(Arm):
    def __init__(self, cfg: CanArmConfig | None = None, robot: RobotModel | None = None, connect_timeout: float = 1.0) -> None:
        self.cfg = cfg or CanArmConfig()
        self.robot = robot or RobotModel()
        self.vmax = self.robot.cfg.arm.max_joint_speed
        self._cv = threading.Condition()
        self._q: np.ndarray | None = None
        self._q_stamp = 0
        self._states = SetPairer()
        db = database()
        self._state_ids = {db.get_message_by_name(n).frame_id for n in ("ARM_STATE_A", "ARM_STATE_B")}
        self._status: dict = {"Mode": 0, "Enabled": 0, "Moving": 0, "Stowed": 0, "FaultCode": 0, "RxRejected": 0}
        self._status_seen = False
        self._status_stamp = 0  # monotonic ns of the last ARM_STATUS
        self._status_n = 0  # ARM_STATUS frames received (start-up counter sync waits on it)
        self._closed = False
        # sending and checking `_closed` are one step under `_tx` (as in CanIgniter): close() sets
        # `_closed` under it, so no target or command of a thread that passed an earlier check can
        # follow close()'s STOP (a target after STOP puts the gateway back into TRACKING)
        self._tx = threading.Lock()
        self.last_stream = StreamStats()
        self.link = CanLink(
            self.cfg.bus,
            self.cfg.heartbeat,
            own_heartbeat="HB_HOST_ARM",
            own_node=NODE_HOST_ARM,
            peer_heartbeat="HB_ARM_GW",
            consume={"ARM_STATE_A", "ARM_STATE_B", "ARM_STATUS"},
            on_frame=self._on_frame,
            max_counter_jump=self.cfg.max_counter_jump,
            on_reject=self._on_reject,
        )
        try:
            self.link.wait_peer(connect_timeout)
            self._wait(lambda: self._q is not None and self._status_seen, time.monotonic() + connect_timeout, "first arm state")
            # host start-up procedure (can.md): a gateway that outlived a previous host expects that
            # host's next ARM_CMD counter; NOPs bring it in step so the first command is accepted
            self.sync_rounds = sync_counter(self._cv, self.link, "ARM_CMD", lambda: (self._status_n, self._status["RxRejected"]),
                                            time.monotonic() + connect_timeout)
        except BaseException:
            self.link.close()
            raise

    # ---- rx (Notifier thread) ----------------------------------------------------------------
    def _on_reject(self, msg) -> None:
        if not msg.is_extended_id and msg.arbitration_id in self._state_ids:
            with self._cv:
                self._states.interrupt()  # a rejected half between A and B breaks the set

    def _on_frame(self, name: str, sig: dict, stamp: float = 0.0) -> None:
        with self._cv:
            if name == "ARM_STATE_A":
                self._states.a(int(sig["Counter"]), (sig["J1_Position"], sig["J2_Position"], sig["J3_Position"]), stamp)
                return
            if name == "ARM_STATE_B":
                q = self._states.b(int(sig["Counter"]), (sig["J4_Position"], sig["J5_Position"], sig["J6_Position"]), stamp)
                if q is None:  # lone, late or interleaved half: dropped, counted
                    link = getattr(self, "link", None)  # None while the constructor runs
                    if link is not None:
                        link.receiver.reject("pair")
                    return
                self._q = np.array(q)
                self._q_stamp = time.monotonic_ns()
            elif name == "ARM_STATUS":
                self._status = {k: int(v) for k, v in sig.items()}
                self._status_seen = True
                self._status_stamp = time.monotonic_ns()
                self._status_n += 1
            self._cv.notify_all()

    # ---- helpers -----------------------------------------------------------------------------
    @property
    def fault(self) -> str | None:
        code, mode = self._status["FaultCode"], self._status["Mode"]
        if mode not in ARM_MODES:  # a mode this host does not know: never drive an arm in it
            return f"unknown_mode_{mode}"
        if mode != 4 and not code:
            return None
        return ARM_FAULTS.get(code) or f"fault_{code}"  # mode FAULT always reports a fault

    @property
    def mode(self) -> str:
        return ARM_MODES.get(self._status["Mode"], "unknown")

    def _joints(self) -> np.ndarray:
        with self._cv:
            return self._q.copy()

    def _check(self) -> None:
        if self._closed:
            raise LinkLost("adapter closed")
        try:
            self.link.check()
        except LinkLost:
            self._command(ARM_STOP)
            raise

    def _command(self, cmd: int) -> None:
        """Send ARM_CMD `cmd`; once closed only STOP goes out (anything else raises LinkLost)."""
        with self._tx:
            if self._closed and cmd != ARM_STOP:
                raise LinkLost("adapter closed")
            self.link.send(self.link.encoder.encode("ARM_CMD", {"Command": cmd}))

    def _wait(self, pred: Callable[[], bool], deadline: float, what: str, on_poll: Callable[[], None] | None = None) -> None:
        wait_for(self._cv, self.link, pred, deadline, what, on_poll)

    def _poller(self, on_state: StateCallback | None) -> Callable[[], None] | None:
        """A function handing new joint-state samples to `on_state`, at most one per
        ON_STATE_PERIOD_NS (a state costs two forward-kinematics solves, and `poll` runs in the
        500 Hz streaming loop); None without a callback."""
        if on_state is None:
            return None
        notify, seen = StateNotifier(on_state), [0]

        def poll() -> None:
            stamp = self._q_stamp
            if stamp - seen[0] >= ON_STATE_PERIOD_NS:
                seen[0] = stamp
                notify(self.state())

        return poll

    def _ensure_enabled(self, deadline: float) -> None:
        if self._status["Enabled"]:
            return
        self._command(ARM_ENABLE)
        self._wait(lambda: bool(self._status["Enabled"]) or self.fault is not None, min(deadline, time.monotonic() + self.cfg.enable_timeout), "arm enable")

    def _send_target(self, q: np.ndarray) -> None:
        """One ARM_TARGET_A/B set, both halves under `_tx` (no command between them); LinkLost once closed."""
        enc = self.link.encoder
        with self._tx:
            if self._closed:
                raise LinkLost("adapter closed")
            c = enc.next_counter("ARM_TARGET_A")
            enc.next_counter("ARM_TARGET_B")  # both ids advance together (shared value)
            self.link.send(enc.encode("ARM_TARGET_A", {"J1_Target": q[0], "J2_Target": q[1], "J3_Target": q[2]}, counter=c))
            self.link.send(enc.encode("ARM_TARGET_B", {"J4_Target": q[3], "J5_Target": q[4], "J6_Target": q[5]}, counter=c))

    def _fail(self, reason: str) -> MoveResult:
        self._command(ARM_STOP)
        return MoveResult(False, reason, final=self._joints())

    def stream(self, traj: Callable[[float], np.ndarray], duration: float, deadline: float,
               on_poll: Callable[[], None] | None = None) -> MoveResult | None:
        """Stream traj(t) for t in (0, duration] at the configured rate (absolute-time ticks).

        Trajectory time advances one period per target sent, not with the wall clock: if the
        host stalls (loaded CPU), the motion pauses instead of jumping ahead, so consecutive
        targets never differ by more than one period of motion (the gateway faults on jumps).
        Ticks late by more than 5 periods are skipped, never burst.
        Returns None when the whole trajectory was sent, a failed MoveResult on a gateway fault;
        raises LinkLost / DriverTimeout (after STOP). Stats of the last stream: `last_stream`.
        `on_poll` runs after every target sent (see `_poller`).
        """
        period = 1.0 / self.cfg.stream_rate_hz
        st = self.last_stream = StreamStats()
        t0 = time.monotonic()
        tick = t0
        k = 0
        while True:
            tick += period
            now = time.monotonic()
            if tick > now:
                time.sleep(tick - now)
            elif now - tick > 5 * period:  # badly late: re-anchor instead of bursting
                st.overruns += 1
                tick = now
            k += 1
            self._check()
            if self.fault is not None:
                st.duration_s = time.monotonic() - t0
                return self._fail(self.fault)
            if time.monotonic() >= deadline:
                self._command(ARM_STOP)
                raise DriverTimeout("arm move not finished within its timeout")
            if time.monotonic_ns() - self._q_stamp > self.cfg.state_timeout * 1e9:
                # streaming blind: stop rather than guess; then tell link loss from lost state frames
                st.duration_s = time.monotonic() - t0
                self._command(ARM_STOP)
                self.link.wait_lost(self.cfg.heartbeat.timeout)
                self._check()
                return self._fail("state_stale")
            t = k * period
            self._send_target(traj(min(t, duration)))
            st.sent += 1
            if on_poll is not None:
                on_poll()
            if t >= duration:
                st.duration_s = time.monotonic() - t0
                return None

    # ---- Arm ---------------------------------------------------------------------------------
    def move_joints(self, q: np.ndarray, timeout: float, on_state: StateCallback | None = None) -> MoveResult:
        deadline = time.monotonic() + timeout
        self._check()
        poll = self._poller(on_state)
        q = np.asarray(q, dtype=float).reshape(6)
        if not np.all(np.isfinite(q)) or not within_limits(self.robot, q):
            return MoveResult(False, "joint_limit", final=self._joints())
        if self.fault is not None:
            return MoveResult(False, self.fault, final=self._joints())
        self._ensure_enabled(deadline)
        if self.fault is not None:
            return MoveResult(False, self.fault, final=self._joints())
        traj = MinJerk(self._joints(), q, self.vmax)
        failed = self.stream(traj, traj.duration, deadline, poll)
        if failed is not None:
            return failed
        try:
            self._wait(
                lambda: self.fault is not None or float(np.max(np.abs(self._q - q))) < self.cfg.at_target_tol,
                deadline,
                "the arm to reach its target",
                poll,
            )
        except DriverTimeout:
            self._command(ARM_STOP)
            raise
        except LinkLost:
            self._command(ARM_STOP)
            raise
        if self.fault is not None:
            return self._fail(self.fault)
        return MoveResult(True, final=self._joints(), extra={"duration_s": traj.duration, "sent": self.last_stream.sent})

    def move_to_pose(self, frame: str, T_base: np.ndarray, timeout: float, on_state: StateCallback | None = None) -> MoveResult:
        deadline = time.monotonic() + timeout
        self._check()
        sol = solve_ik(self.robot, frame, T_base, self._joints())
        if sol is None:
            return MoveResult(False, "ik_failed", final=self._joints())
        return self.move_joints(sol, max(0.0, deadline - time.monotonic()), on_state)

    def stow(self, timeout: float, on_state: StateCallback | None = None) -> MoveResult:
        deadline = time.monotonic() + timeout
        self._check()
        poll = self._poller(on_state)
        if self.fault is not None:
            return MoveResult(False, self.fault, final=self._joints())
        self._ensure_enabled(deadline)
        self._command(ARM_STOW)
        # the gateway reports STOWING (mode 3) until it holds at the stow joints
        try:
            stow_q = np.array(self.robot.cfg.arm.stow_joints)
            self._wait(
                lambda: self.fault is not None
                or (self._status["Stowed"] and self._status["Mode"] == 1 and float(np.max(np.abs(self._q - stow_q))) < self.cfg.at_target_tol),
                deadline,
                "stow",
                poll,
            )
        except (DriverTimeout, LinkLost):
            self._command(ARM_STOP)
            raise
        if self.fault is not None:
            return self._fail(self.fault)
        return MoveResult(True, final=self._joints())

    def reset(self, timeout: float = 1.0) -> None:
        """Clear a latched gateway fault (the arm is disabled afterwards; the next move enables it)."""
        self._check()
        self._command(ARM_RESET)
        self._wait(lambda: self.fault is None, time.monotonic() + timeout, "fault reset")

    def state(self) -> ArmState:
        with self._cv:
            q, stamp, moving = self._q.copy(), self._q_stamp, bool(self._status["Moving"])
            status_stamp = self._status_stamp
        # joints or status older than state_timeout: the arm may have sagged or latched a fault
        # this host has not heard of, so the state says so (the ignition interlock denies on any
        # fault) while the gateway's heartbeat alone still says the link is up
        oldest = min(stamp, status_stamp)
        if not self.link.ok:
            fault = "link_lost"
        elif time.monotonic_ns() - oldest > self.cfg.state_timeout * 1e9:
            fault = "state_stale"
        else:
            fault = self.fault
        return arm_state(self.robot, q, moving, stamp, fault)

    @property
    def rx_stats(self):
        return self.link.receiver.stats

    def close(self) -> None:
        with self._tx:
            if self._closed:
                return
            self._closed = True  # first: from here only STOP goes out
        try:
            self._command(ARM_STOP)  # hold, not DISABLE: a disabled Z1 has no holding torque
        finally:
            self.link.close()
