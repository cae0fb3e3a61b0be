"""Simulated flame igniter board and an in-process `Igniter` driver.

`IgniterBoard` is the board's firmware logic, the contract a real board must meet:
* it opens the valve and sparks only when ARMED, fault-free, fuelled, with the host present,
  and only while IGNITE keep-alives keep arriving;
* a keep-alive gap > `keepalive_timeout` (default 80 ms, so the valve is shut within 100 ms of
  the last keep-alive), a rejected command frame while the valve is open (bad checksum,
  stale/repeated counter, wrong length) or host heartbeat loss shuts the valve AND disarms the
  board ("trip": Event KEEPALIVE_TIMEOUT / BAD_FRAME / HOST_LOST); burning again needs an
  explicit ARM, so resumed keep-alives never re-light on their own. An IGNITE arriving after the
  gap has already expired trips too (it does not revive the valve);
* an ignition trial is bounded (`trial_time`): no flame by then latches IGNITION_FAILED;
* burning consumes fuel (`fuel_per_s`); empty latches FUEL_EMPTY; a flame-out latches FLAME_OUT;
* latched faults keep the valve shut until RESET_FAULT (then ARM again);
* `event` holds the last event until another replaces it; an accepted ARM clears it.
Time is passed in (seconds); the wire gateway uses the monotonic clock, the in-process driver a
`SimClock`. Randomness (ignition failure probability) comes from a seeded generator.
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from typing import Callable

from drivers.interfaces import DriverTimeout, Igniter, IgniterFault, IgniterState, LinkLost, MoveResult, credited_flame_s

from .sim_clock import SimClock


# events with which the board shuts the valve and disarms itself (ignite() reports them as reason)
TRIP_EVENTS = ("keepalive_timeout", "bad_frame", "host_lost")


@dataclass(frozen=True)
class IgniterParams:
    keepalive_timeout: float = 0.08  # s without a valid IGNITE -> valve shut
    timer_period: float = 0.001  # the firmware's timer: a gap is noticed on its first tick after expiry
    light_delay: float = 0.12  # s from the first IGNITE to a detected flame
    trial_time: float = 0.5  # s: no flame by then -> IGNITION_FAILED (latched)
    fuel_per_s: float = 1.0 / 600.0  # tank fraction burnt per second of flame (10 min tank)
    p_fail_light: float = 0.0  # chance that one ignition trial fails (Monte Carlo)
    seed: int = 0


@dataclass
class IgniterFaultHooks:
    fail_to_light: bool = False  # every trial fails until cleared
    flame_out: bool = False  # one-shot: the burning flame goes out (latched FLAME_OUT)
    flame_out_after: float | None = None  # one-shot: flame goes out after this many s of burning
    hardware_fault: bool = False  # one-shot: latched HARDWARE fault
    link_lost: bool = False  # in-process driver only: LinkLost


class IgniterBoard:
    def __init__(self, params: IgniterParams | None = None, fuel: float = 1.0) -> None:
        self.p = params or IgniterParams()
        self.hooks = IgniterFaultHooks()
        self.rng = random.Random(self.p.seed)
        self.armed = False
        self.valve_open = False  # trial in progress or burning
        self.flame_on = False
        self.fault: str | None = None
        self.event: str | None = None
        self.fuel = float(fuel)
        self.host_present = True  # the wire gateway sets this from the host heartbeat
        self.rejected = 0
        self._last_keepalive = 0.0
        self._trial_start = 0.0
        self._flame_start = 0.0
        self._trial_fails = False
        self._last_tick: float | None = None
        self.flame_off_at: float | None = None  # time of the last valve closing (bench)

    # ---- commands --------------------------------------------------------------------------
    def arm(self, now: float) -> None:
        if self.fault is None and self.host_present and self.fuel > 0.0:
            self.armed = True
            self.event = None  # a fresh arming period: Event reports only what happens from now

    def disarm(self, now: float) -> None:
        self._shut(now, "extinguished")
        self.armed = False

    def extinguish(self, now: float) -> None:
        self._shut(now, "extinguished")

    def reset(self, now: float) -> None:
        self._shut(now, None)
        self.fault = None
        self.armed = False

    def ignite(self, now: float) -> None:
        """IGNITE: starts a trial, and is the keep-alive while the valve is open."""
        if not (self.armed and self.fault is None and self.host_present and self.fuel > 0.0):
            self.event = "not_armed"
            return
        if self.valve_open and now - self._last_keepalive > self.p.keepalive_timeout:
            self._gap_expired(now, self._last_tick)  # too late: the gap expired before this frame
            return
        self._last_keepalive = now
        if not self.valve_open:
            self.valve_open = True
            self._trial_start = now
            self._trial_fails = self.hooks.fail_to_light or self.rng.random() < self.p.p_fail_light

    def frame_rejected(self, now: float, command: bool = True) -> None:
        """A frame the board's receiver rejected: counted (RxRejected), never acted on. A rejected
        IGN_CMD while the valve is open (trial or flame) trips the board: valve shut, disarmed."""
        self.rejected += 1
        if command and self.valve_open:
            self._trip(now, "bad_frame")

    def bad_frame(self, now: float) -> None:
        """A rejected IGN_CMD (see `frame_rejected`)."""
        self.frame_rejected(now, command=True)

    def host_lost(self, now: float) -> None:
        self.host_present = False
        self._trip(now, "host_lost")

    # ---- time ------------------------------------------------------------------------------
    def tick(self, now: float) -> None:
        """The firmware's timer. The board runs on its own clock: when the host was stalled and
        ticks late, the valve shut (and the fuel stopped burning) when the board's own timer
        noticed the keep-alive gap, not when the host came back."""
        last_tick = self._last_tick
        self._last_tick = now
        if self.hooks.hardware_fault:
            self.hooks.hardware_fault = False
            self._latch(now, "hardware")
        if not self.valve_open:
            return
        if now - self._last_keepalive > self.p.keepalive_timeout:
            self._gap_expired(now, last_tick)
            return
        dt = 0.0 if last_tick is None else max(0.0, now - last_tick)
        if not self.flame_on:
            if self._trial_fails or self.hooks.fail_to_light:
                if now - self._trial_start >= self.p.trial_time:
                    self._latch(now, "ignition_failed")
            elif now - self._trial_start >= self.p.light_delay:
                self.flame_on = True
                self._flame_start = now
            return
        self._burn(dt)
        if self.fuel <= 0.0:
            self._latch(now, "fuel_empty")
        elif self.hooks.flame_out or (
            self.hooks.flame_out_after is not None and now - self._flame_start >= self.hooks.flame_out_after
        ):
            self.hooks.flame_out, self.hooks.flame_out_after = False, None
            self._latch(now, "flame_out")

    def _burn(self, dt: float) -> None:
        self.fuel = max(0.0, self.fuel - self.p.fuel_per_s * dt)

    def _gap_deadline(self, now: float) -> float:
        """When the board's own timer noticed the keep-alive gap (≤ now)."""
        return min(now, self._last_keepalive + self.p.keepalive_timeout + self.p.timer_period)

    def _gap_expired(self, now: float, last_tick: float | None) -> None:
        """Trip as the board's timer did; a flame burnt fuel from the last tick until then."""
        t = self._gap_deadline(now)
        if self.flame_on and last_tick is not None:
            self._burn(max(0.0, t - last_tick))
        self._trip(t, "keepalive_timeout")

    def _shut(self, now: float, event: str | None) -> None:
        """Valve shut; `event` (if any) is reported only when the valve was actually open."""
        if self.valve_open or self.flame_on:
            self.flame_off_at = now
            if event is not None:
                self.event = event
        self.valve_open = False
        self.flame_on = False

    def _trip(self, now: float, event: str) -> None:
        """Valve shut and disarmed by the board itself; Event says why (if it was armed or open)."""
        if self.armed or self.valve_open or self.flame_on:
            self.event = event
        self._shut(now, event)
        self.armed = False

    def _latch(self, now: float, fault: str) -> None:
        self._shut(now, None)
        self.fault = fault
        self.armed = False

    @property
    def igniting(self) -> bool:
        return self.valve_open and not self.flame_on


class SimIgniterDriver(Igniter):
    """In-process igniter on a simulated clock, with the same contract as `CanIgniter`."""

    def __init__(
        self,
        board: IgniterBoard | None = None,
        clock: SimClock | None = None,
        keepalive_rate_hz: float = 50.0,
        poll_period: float = 0.005,
    ) -> None:
        self.board = board or IgniterBoard()
        self.clock = clock or SimClock()
        self.keepalive_period = 1.0 / keepalive_rate_hz
        self.dt = poll_period
        self._closed = False

    @property
    def hooks(self) -> IgniterFaultHooks:
        return self.board.hooks

    def _check_link(self) -> None:
        if self._closed:
            raise LinkLost("adapter closed")
        if self.board.hooks.link_lost:
            self.board.host_lost(self.clock.now())
            raise LinkLost("simulated link loss")

    def _tick(self) -> None:
        self.clock.sleep(self.dt)
        self.board.tick(self.clock.now())

    def arm(self, timeout: float) -> None:
        self._check_link()
        if self.board.fault:
            raise IgniterFault(f"igniter fault latched: {self.board.fault} (reset_fault() first)")
        self.board.arm(self.clock.now())
        self._tick()
        if not self.board.armed:
            raise IgniterFault("igniter refused to arm (no fuel?)")

    def disarm(self) -> None:
        self.board.disarm(self.clock.now())

    def extinguish(self) -> None:
        self.board.extinguish(self.clock.now())

    def reset_fault(self, timeout: float = 1.0) -> None:
        self._check_link()
        self.board.reset(self.clock.now())

    def ignite(self, duration: float, permit: Callable[[], bool], timeout: float) -> MoveResult:
        flame_s = 0.0
        t0 = self.clock.now()
        try:
            self._check_link()
            b = self.board
            if b.fault:
                return MoveResult(False, b.fault, extra={"flame_s": 0.0})
            if not b.armed:
                return MoveResult(False, "not_armed", extra={"flame_s": 0.0})
            if not permit():
                return MoveResult(False, "permit_denied", extra={"flame_s": 0.0})
            flame_t0: float | None = None
            next_ka = self.clock.now()
            last_ka = next_ka
            while True:
                now = self.clock.now()
                if b.flame_on and flame_t0 is None:
                    flame_t0 = now
                if flame_t0 is not None:
                    flame_s = credited_flame_s(flame_t0, now, last_ka)
                    if flame_s >= duration:
                        return MoveResult(True, extra={"flame_s": flame_s})
                    if not b.flame_on:
                        return MoveResult(False, self._off_reason(), extra={"flame_s": flame_s})
                if b.fault:
                    return MoveResult(False, b.fault, extra={"flame_s": flame_s})
                if not b.armed:  # the board tripped (keep-alive gap, bad frame, host lost): never re-armed here
                    return MoveResult(False, self._off_reason(), extra={"flame_s": flame_s})
                if not permit():
                    return MoveResult(False, "permit_dropped", extra={"flame_s": flame_s})
                if now - t0 >= timeout:
                    raise DriverTimeout(f"ignite not complete within {timeout:.3f} s")
                if now >= next_ka:
                    b.ignite(now)
                    last_ka = now
                    next_ka += self.keepalive_period
                self._check_link()
                self._tick()
        finally:
            self.extinguish()

    def _off_reason(self) -> str:
        b = self.board
        if b.fault:
            return b.fault
        if not b.armed:
            return b.event if b.event in TRIP_EVENTS else "disarmed"
        return "flame_lost"

    def state(self) -> IgniterState:
        b = self.board
        fault = "link_lost" if b.hooks.link_lost else b.fault
        return IgniterState(armed=b.armed, flame_on=b.flame_on, fuel=b.fuel, stamp_ns=self.clock.now_ns(), fault=fault)

    def close(self) -> None:
        if not self._closed:
            self.extinguish()
            self._closed = True
