"""Simulated Spot body: holonomic SE(2) with speed / acceleration / yaw-rate limits.

The model steps on a `SimClock`: virtual time for in-process Monte Carlo (a 10 m walk costs
microseconds and is bit-for-bit repeatable for a seed), real time for the wire-level bench
(the zenoh body server steps it from its state loop). Fault hooks (motion failure, slip,
E-stop, freeze, power) are plain methods so a later fault-injection layer can drive them.

`SimBodyDriver` is the in-process `Body` driver: no transport, virtual time by default.
"""

from __future__ import annotations

import math
import threading
from typing import Callable
import numpy as np

from capm_field.config import BodyConfig
from capm_field.geometry import SE2, wrap_angle
from drivers.body_server import MoveStatus
from drivers.interfaces import Body, BodyState, DriverTimeout, EStopActive, LinkLost, MoveResult, StateCallback, StateNotifier

from .sim_clock import SimClock

_SUBSTEP_NS = 5_000_000  # integration step (5 ms): small against the 0.8 m/s² ramps
_ARRIVE_TOL = 1e-4  # m and rad: the profile ends exactly on the goal, this only absorbs rounding


class SimBody:
    """The physics and the fault hooks; thread-safe (the wire server steps it from its loop
    while queries arrive on zenoh threads)."""

    def __init__(
        self,
        config: BodyConfig | None = None,
        clock: SimClock | None = None,
        seed: int = 0,
        pose: SE2 = SE2(0.0, 0.0, 0.0),
        noise_xy: float = 0.005,
        noise_yaw: float = 0.005,
    ) -> None:
        self.config = config or BodyConfig()
        self.clock = clock or SimClock()
        self._rng = np.random.default_rng(seed)
        self.noise_xy, self.noise_yaw = noise_xy, noise_yaw
        self._lock = threading.RLock()
        self._pose = pose
        self._v = 0.0  # translation speed along the path (m/s)
        self._goal: SE2 | None = None
        self._cmd_id = 0
        self._deadline_ns: int | None = None
        self._status: MoveStatus | None = None
        self._t = self.clock.now_ns()
        # meters
        self.odometry_m = 0.0
        self.yaw_travelled = 0.0
        self.moves = 0
        # safety / power state
        self.powered = True
        self._estop: dict[str, str] = {}  # source -> reason; engaged while non-empty
        self.frozen = False
        # pending faults (each consumed by the next move)
        self._fail_after: tuple[float, str] | None = None
        self._slip: SE2 | None = None
        self._walked_s = 0.0  # time spent walking in the current move
        self._events: list[tuple[int, int, Callable[[], None]]] = []  # (t_ns, order, fn), sorted
        self._in_step = False

    # ---- commands ----------------------------------------------------------------------------
    def start_move(self, goal: SE2, cmd_id: int, timeout_s: float | None = None) -> None:
        """Start walking to `goal`. Refusals raise EStopActive; not powered ends the move at once."""
        with self._lock:
            self.step_to(self.clock.now_ns())
            if self._goal is not None:
                self._finish("stopped", "preempted")
            if self._estop:
                raise EStopActive(f"E-stop engaged ({', '.join(sorted(self._estop.values()))})")
            self._cmd_id = cmd_id
            self._deadline_ns = None if timeout_s is None else self._t + int(timeout_s * 1e9)
            if not self.powered:
                self._status = MoveStatus(cmd_id, "failed", "not_powered", self._pose)
                return
            self._goal = SE2(float(goal.x), float(goal.y), float(wrap_angle(goal.yaw)))
            self._status = MoveStatus(cmd_id, "running")
            self._walked_s = 0.0
            self.moves += 1

    def stop(self, reason: str = "stop_requested") -> None:
        with self._lock:
            self.step_to(self.clock.now_ns())
            if self._goal is not None:
                self._finish("stopped", reason)
            self._v = 0.0

    def status(self) -> MoveStatus | None:
        return self._status

    @property
    def pose(self) -> SE2:
        return self._pose

    @property
    def moving(self) -> bool:
        return self._goal is not None

    @property
    def estop(self) -> bool:
        return bool(self._estop)

    @property
    def estop_reason(self) -> str | None:
        return ", ".join(sorted(self._estop.values())) or None

    # ---- fault hooks -------------------------------------------------------------------------
    def inject_motion_failure(self, after_s: float = 0.0, reason: str = "blocked") -> None:
        """The next move aborts after `after_s` s of walking (status 'failed', `reason`)."""
        self._fail_after = (after_s, reason)

    def inject_slip(self, dx: float, dy: float, dyaw: float = 0.0) -> None:
        """The next move reports success but ends offset by (dx, dy, dyaw) in the field frame."""
        self._slip = SE2(dx, dy, dyaw)

    def press_estop(self, source: str = "hardware", reason: str = "estop_pressed") -> None:
        with self._lock:
            self.step_to(self.clock.now_ns())
            self._estop[source] = reason
            if self._goal is not None:
                self._finish("estop", reason)
            self._v = 0.0

    def release_estop(self, source: str = "hardware") -> None:
        with self._lock:
            self._estop.pop(source, None)

    def set_power(self, on: bool) -> None:
        with self._lock:
            if not on:
                self.stop("power_off")
            self.powered = on

    def schedule(self, delay_s: float, fn: Callable[[], None]) -> None:
        """Run `fn` (e.g. `press_estop`) when simulated time reaches now + `delay_s`, from the
        stepping itself: faults land mid-move, deterministically, on either clock."""
        with self._lock:
            self._events.append((self._t + int(delay_s * 1e9), len(self._events), fn))
            self._events.sort(key=lambda e: e[:2])

    def displace(self, dx: float, dy: float, dyaw: float = 0.0) -> None:
        """An external push: the standing (or walking) body is moved by (dx, dy, dyaw) now."""
        with self._lock:
            p = self._pose
            self._pose = SE2(p.x + dx, p.y + dy, float(wrap_angle(p.yaw + dyaw)))

    def freeze(self, frozen: bool = True) -> None:
        """Stop responding (drivers and the wire server honour it); the physics keeps its state."""
        self.frozen = frozen

    # ---- physics -----------------------------------------------------------------------------
    def step_to(self, t_ns: int) -> None:
        """Integrate up to simulated time `t_ns` in fixed substeps."""
        with self._lock:
            if self._in_step:  # a scheduled event calling back into a hook
                return
            self._in_step = True
            try:
                while self._t < t_ns:
                    dt_ns = min(_SUBSTEP_NS, t_ns - self._t)
                    self._t += dt_ns
                    if self._goal is not None:
                        self._integrate(dt_ns * 1e-9)
                    while self._events and self._events[0][0] <= self._t:
                        self._events.pop(0)[2]()
            finally:
                self._in_step = False

    def _integrate(self, dt: float) -> None:
        cfg, goal, p = self.config, self._goal, self._pose
        assert goal is not None
        if self._deadline_ns is not None and self._t >= self._deadline_ns:
            self._finish("timeout", "move_deadline")
            return
        dx, dy = goal.x - p.x, goal.y - p.y
        dist = math.hypot(dx, dy)
        dyaw = float(wrap_angle(goal.yaw - p.yaw))
        # Trapezoidal speed: accelerate, cruise, brake so that v reaches 0 exactly at the goal.
        v = min(cfg.max_speed, self._v + cfg.max_accel * dt, math.sqrt(2.0 * cfg.max_accel * dist))
        step = min(dist, v * dt)
        yaw_step = math.copysign(min(abs(dyaw), cfg.max_yaw_rate * dt), dyaw)
        nx, ny = (p.x + dx / dist * step, p.y + dy / dist * step) if dist > 0 else (p.x, p.y)
        self._pose = SE2(nx, ny, float(wrap_angle(p.yaw + yaw_step)))
        self._v = v if step < dist else 0.0
        self.odometry_m += step
        self.yaw_travelled += abs(yaw_step)
        self._walked_s += dt
        if self._fail_after is not None and self._walked_s >= self._fail_after[0]:
            reason = self._fail_after[1]
            self._fail_after = None
            self._finish("failed", reason)
            return
        if dist - step <= _ARRIVE_TOL and abs(dyaw - yaw_step) <= _ARRIVE_TOL:
            self._arrive(goal)

    def _arrive(self, goal: SE2) -> None:
        # Pose noise is drawn on arrival only: where the body ends up, not how it got there.
        n = self._rng.normal(0.0, 1.0, 3)
        final = SE2(float(goal.x + self.noise_xy * n[0]), float(goal.y + self.noise_xy * n[1]), float(wrap_angle(goal.yaw + self.noise_yaw * n[2])))
        if self._slip is not None:
            s, self._slip = self._slip, None
            final = SE2(final.x + s.x, final.y + s.y, float(wrap_angle(final.yaw + s.yaw)))
        self._pose = final
        self._finish("succeeded", None)

    def _finish(self, status: str, reason: str | None) -> None:
        self._goal, self._v, self._deadline_ns = None, 0.0, None
        self._status = MoveStatus(self._cmd_id, status, reason, self._pose)

    def snapshot(self) -> BodyState:
        with self._lock:
            fault = None
            if self._status is not None and self._status.status == "failed":
                fault = self._status.reason
            return BodyState(
                pose=self._pose,
                moving=self._goal is not None,
                powered=self.powered,
                estop=bool(self._estop),
                stamp_ns=self._t,
                odometry_m=self.odometry_m,
                fault=fault,
            )


class SimBodyDriver(Body):
    """In-process `Body` on a `SimBody`: virtual time, deterministic, no transport.

    `move_to` steps the simulation until the move ends; `timeout` is in simulated seconds.
    Outcomes (the body contract, docs/drivers.md): arrived → ok=True; aborted by a fault or
    stop → ok=False with the reason; E-stop → EStopActive; timeout → body stopped, DriverTimeout.
    A frozen body makes every waiting call time out.
    """

    def __init__(self, sim: SimBody | None = None, step_s: float = 0.02) -> None:
        self.sim = sim or SimBody()
        self.step_s = step_s
        self._next_id = 0
        self._closed = False
        self.link_lost = False  # fault hook: the in-process stand-in for a lost zenoh link

    def _check_link(self) -> None:
        if self.link_lost:
            self.sim.stop("link_lost")  # the robot side stops itself when its commander vanishes
            raise LinkLost("simulated body link loss")

    def move_to(self, goal: SE2, timeout: float, on_state: StateCallback | None = None) -> MoveResult:
        if not all(math.isfinite(v) for v in goal.as_tuple()):
            raise ValueError(f"goal must be finite, got {goal}")
        self._check_link()
        sim, clock = self.sim, self.sim.clock
        notify = StateNotifier(on_state)
        if sim.frozen:
            clock.advance(timeout)
            raise DriverTimeout(f"body did not answer within {timeout} s (frozen)")
        self._next_id += 1
        t0, d0 = clock.now_ns(), sim.odometry_m
        sim.start_move(goal, self._next_id)
        deadline = t0 + int(timeout * 1e9)
        while True:
            st = sim.status()
            if st is not None and st.cmd_id == self._next_id and st.done:
                break
            if clock.now_ns() >= deadline:
                sim.stop("timeout")
                raise DriverTimeout(f"move to {goal} not done within {timeout} s")
            clock.advance(min(self.step_s, (deadline - clock.now_ns()) * 1e-9))
            sim.step_to(clock.now_ns())
            notify(sim.snapshot())
        extra = {"cmd_id": st.cmd_id, "duration_s": (clock.now_ns() - t0) * 1e-9, "distance_m": sim.odometry_m - d0}
        if st.status == "estop":
            raise EStopActive(f"E-stop engaged during the move ({st.reason})")
        return MoveResult(ok=st.status == "succeeded", reason=st.reason, final=st.final, extra=extra)

    def stop(self) -> None:
        self.sim.stop()

    def state(self) -> BodyState:
        self._check_link()
        return self.sim.snapshot()

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.sim.stop("closed")
