"""`CanIgniter`: the flame igniter board over CAN (protocol: docs/protocols/can.md).

Safety design: the board keeps the valve open only while valid IGNITE keep-alives arrive
(gap > 80 ms -> off). This adapter sends them at a fixed rate from inside `ignite()` and only
while `permit()` is True, the flame hold time has not elapsed, the link is up and the board
reports no fault; `permit()` is re-checked every `poll_period` (5 ms). EXTINGUISH is sent on
every exit path of `ignite()` (finally), by `disarm()` and by `close()`; if the host freezes
or the bus dies the keep-alives stop and the board shuts the valve on its own.

A keep-alive gap, a rejected command frame or host loss makes the board shut the valve and
disarm itself ("trip"); `ignite()` never re-arms: it ends (flame off) with the trip event as
reason (`keepalive_timeout`, `bad_frame`, `host_lost`; `disarmed` for anything else), and the
caller must `arm()` again to burn.

Start-up: the constructor waits for the board's heartbeat and status, then synchronises the
IGN_CMD counter with NOPs (`sync_counter`, can.md "Host start-up"): a board that kept running
while the host process restarted expects the old host's next counter and would otherwise reject
the first command (e.g. ARM) and only resync on it.
"""

from __future__ import annotations

import threading
import time
from typing import Callable

from .can.codec import (
    IGN_ARM,
    IGN_DISARM,
    IGN_EVENTS,
    IGN_EXTINGUISH,
    IGN_FAULTS,
    IGN_IGNITE,
    IGN_RESET,
    NODE_HOST_IGN,
)
from .can.config import CanIgniterConfig
from .can.link import CanLink, sync_counter, wait_for
from .interfaces import DriverTimeout, Igniter, IgniterFault, IgniterState, LinkLost, MoveResult, credited_flame_s

# board events that come with the board disarming itself (reported as ignite()'s reason)
TRIP_EVENTS = ("keepalive_timeout", "bad_frame", "host_lost")
# the board shuts the valve and disarms no later than this after the last valid IGNITE (can.md)
KEEPALIVE_BOUND_S = 0.1
# a status this long after the previous one is the board's current one, not one of a backlog
# drained after a host stall (the board sends one every 20 ms; a backlog arrives back to back)
DRAINED_S = 0.008


class CanIgniter(Igniter):
    def __init__(self, cfg: CanIgniterConfig | None = None, connect_timeout: float = 1.0) -> None:
        self.cfg = cfg or CanIgniterConfig()
        self._cv = threading.Condition()
        self._status: dict | None = None
        self._status_stamp = 0
        self._status_n = 0  # IGN_STATUS frames received (start-up counter sync waits on it)
        self._closed = False
        # sending a command and checking `_closed` are one step under `_tx`: close() sets `_closed`
        # under it before its EXTINGUISH, so no IGNITE keep-alive of an ignite() running in another
        # thread can follow that EXTINGUISH (one did, under load, and re-lit the board)
        self._tx = threading.Lock()
        self.keepalives_sent = 0
        self.last_keepalive_ns: int | None = None
        self._last_ignite_ns = 0  # monotonic: any IGNITE sent (the first of an ignite() is not a keep-alive)
        self.disarmed_by: str | None = None  # Event in the status where Armed last went 1 -> 0
        self.link = CanLink(
            self.cfg.bus,
            self.cfg.heartbeat,
            own_heartbeat="HB_HOST_IGN",
            own_node=NODE_HOST_IGN,
            peer_heartbeat="HB_IGN_BOARD",
            consume={"IGN_STATUS"},
            on_frame=self._on_frame,
            max_counter_jump=self.cfg.max_counter_jump,
            on_lost=lambda _reason: self.extinguish(),
        )
        try:
            self.link.wait_peer(connect_timeout)
            self._wait(lambda: self._status is not None, time.monotonic() + connect_timeout, "first igniter status")
            # host start-up procedure (can.md): a board that outlived a previous host expects that
            # host's next counter; NOPs bring it in step so the first real command is accepted
            self.sync_rounds = sync_counter(self._cv, self.link, "IGN_CMD", lambda: (self._status_n, self._status["RxRejected"]),
                                            time.monotonic() + connect_timeout)
        except BaseException:
            self.link.close()
            raise

    # ---- rx (Notifier thread) ----------------------------------------------------------------
    def _on_frame(self, name: str, sig: dict, stamp: float = 0.0) -> None:
        with self._cv:
            new = {k: (v if k == "Fuel" else int(v)) for k, v in sig.items()}
            if self._status is not None and self._status["Armed"] and not new["Armed"]:
                # the board sends a status at once on every change, so this frame's Event is the
                # cause of the disarm (a later IGNITE may overwrite the Event with NOT_ARMED)
                self.disarmed_by = IGN_EVENTS.get(new["Event"]) or "none"
            elif new["Armed"]:
                self.disarmed_by = None
            self._status = new
            self._status_stamp = time.monotonic_ns()
            self._status_n += 1
            self._cv.notify_all()

    # ---- helpers -----------------------------------------------------------------------------
    def _s(self, key: str):
        return self._status[key]

    @property
    def fault(self) -> str | None:
        code = self._s("FaultCode")
        if not self._s("FaultLatched") and not code:
            return None
        return IGN_FAULTS.get(code) or f"fault_{code}"  # a latched fault is always reported

    def _command(self, cmd: int) -> bool:
        with self._tx:
            if self._closed and cmd not in (IGN_EXTINGUISH, IGN_DISARM):
                return False
            sent = self.link.send(self.link.encoder.encode("IGN_CMD", {"Command": cmd}))
            if sent and cmd == IGN_IGNITE:
                self._last_ignite_ns = time.monotonic_ns()
            return sent

    def _wait(self, pred: Callable[[], bool], deadline: float, what: str) -> None:
        wait_for(self._cv, self.link, pred, deadline, what)

    def _check(self) -> None:
        if self._closed:
            raise LinkLost("adapter closed")
        self.link.check()

    # ---- Igniter -----------------------------------------------------------------------------
    def arm(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        self._check()
        if self.fault:
            raise IgniterFault(f"igniter fault latched: {self.fault} (reset_fault() first)")
        self._command(IGN_ARM)
        self._wait(lambda: bool(self._s("Armed")) or self.fault is not None, deadline, "the igniter to arm")
        if self.fault:
            raise IgniterFault(f"igniter fault: {self.fault}")

    def disarm(self) -> None:
        self.extinguish()
        try:
            self._command(IGN_DISARM)
        except Exception:  # noqa: BLE001 - disarm never raises; the board disarms on host loss anyway
            pass

    def extinguish(self) -> None:
        try:
            self._command(IGN_EXTINGUISH)
        except Exception:  # noqa: BLE001 - never raises; keep-alives have stopped, the board shuts itself
            pass

    def reset_fault(self, timeout: float = 1.0) -> None:
        """Clear a latched board fault (the board is disarmed afterwards)."""
        self._check()
        self._command(IGN_RESET)
        self._wait(lambda: self.fault is None, time.monotonic() + timeout, "igniter fault reset")

    def ignite(self, duration: float, permit: Callable[[], bool], timeout: float) -> MoveResult:
        t0 = time.monotonic()
        flame_t0: float | None = None
        flame_s = 0.0

        def result(ok: bool, reason: str | None = None) -> MoveResult:
            return MoveResult(ok, reason, extra={"flame_s": flame_s, "keepalives": sent})

        sent = 0
        try:
            self._check()
            if self.fault:
                return result(False, self.fault)
            if not self._s("Armed"):
                return result(False, "not_armed")
            if not permit():
                return result(False, "permit_denied")
            ka_period = 1.0 / self.cfg.keepalive_rate_hz
            next_ka = time.monotonic()
            last_ka = next_ka  # (the first IGNITE goes out on the first pass)
            while True:
                now = time.monotonic()
                with self._cv:
                    flame, fault, stamp = bool(self._s("FlameOn")), self.fault, self._status_stamp
                    armed = bool(self._s("Armed"))
                if time.monotonic_ns() - stamp > self.cfg.status_timeout * 1e9:
                    # blind: cannot confirm the flame, so stop now; then tell a lost link (LinkLost)
                    # from lost status frames and from a stall of this host, after which the board's
                    # status says what it did meanwhile (it trips on the missing keep-alives: a
                    # `keepalive_timeout`, which the executive re-arms once for)
                    self.extinguish()
                    fresh = self._status_after(stamp, self.cfg.heartbeat.timeout)
                    self._check()
                    with self._cv:
                        armed, fault = bool(self._s("Armed")), self.fault
                    if not fresh or (armed and not fault):
                        return result(False, "status_stale")
                    return result(False, fault or self._off_reason(armed))
                if flame and flame_t0 is None and stamp / 1e9 >= t0:
                    flame_t0 = now
                if flame_t0 is not None:
                    flame_s = credited_flame_s(flame_t0, now, last_ka)
                    if flame_s >= duration:
                        return result(True)
                    if not flame:
                        return result(False, fault or self._off_reason(armed))
                if fault:
                    return result(False, fault)
                if not armed:  # the board tripped (or was disarmed): end here, never re-arm
                    return result(False, self._off_reason(armed))
                if not permit():
                    return result(False, "permit_dropped")
                self._check()
                if now - t0 >= timeout:
                    raise DriverTimeout(f"ignite not complete within {timeout:.3f} s")
                if now >= next_ka:
                    # permit, hold time, link, fault and Armed were all checked just above; the
                    # latest status must still say armed (a trip may have been reported meanwhile)
                    with self._cv:
                        if not self._s("Armed") or self.fault:
                            continue
                    if self._command(IGN_IGNITE):
                        last_ka = time.monotonic()
                        sent += 1
                        self.keepalives_sent += 1
                        self.last_keepalive_ns = time.monotonic_ns()
                    next_ka = max(next_ka + ka_period, now)
                with self._cv:  # wake on a status change or at the next poll
                    self._cv.wait(min(self.cfg.poll_period, max(0.0, next_ka - time.monotonic())))
        finally:
            self.extinguish()
            self._confirm_off(0.2)

    def _status_after(self, stamp_ns: int, timeout: float) -> bool:
        """Wait (≤ timeout, never raises) for the board's current status: one newer than `stamp_ns`
        with none after it for DRAINED_S (after a stall of this host the statuses the board sent
        meanwhile arrive back to back, the oldest first: the first of them still shows the board
        armed, from before its trip), or for the link declared lost. True if a newer status came."""
        end = time.monotonic() + timeout
        with self._cv:
            while self.link.lost_reason is None and not self._closed:
                if self._status_stamp > stamp_ns and time.monotonic_ns() - self._status_stamp >= DRAINED_S * 1e9:
                    return True
                left = end - time.monotonic()
                if left <= 0:
                    break
                self._cv.wait(min(left, DRAINED_S / 2))
            return self._status_stamp > stamp_ns

    def _off_reason(self, armed: bool) -> str:
        """Why the flame / trial ended without a fault: the trip event if the board disarmed."""
        if armed:
            return "flame_lost"
        why = self.disarmed_by
        return why if why in TRIP_EVENTS else "disarmed"

    def _confirm_off(self, timeout: float) -> None:
        """Wait (bounded, never raises) for the board to report the flame off."""
        try:
            self._wait(lambda: not self._s("FlameOn") and not self._s("Igniting"), time.monotonic() + timeout, "flame off")
        except Exception:  # noqa: BLE001 - link gone: the board shuts itself without keep-alives
            pass

    def state(self) -> IgniterState:
        """The board's last status; with the link lost (`fault="link_lost"`) that status is stale, and
        a flame it showed is reported off (and the board disarmed) once `KEEPALIVE_BOUND_S` has passed
        since this host's last IGNITE: the board's keep-alive trip guarantees it (docs/protocols/can.md)."""
        with self._cv:
            s, stamp = dict(self._status), self._status_stamp
        armed, flame, fault = bool(s["Armed"]), bool(s["FlameOn"]), self.fault
        if not self.link.ok:
            fault = "link_lost"
            if flame and (time.monotonic_ns() - self._last_ignite_ns) / 1e9 > KEEPALIVE_BOUND_S:
                armed = flame = False
        return IgniterState(armed=armed, flame_on=flame, fuel=float(s["Fuel"]) / 100.0, stamp_ns=stamp, fault=fault)

    @property
    def rx_stats(self):
        return self.link.receiver.stats

    def close(self) -> None:
        with self._tx:
            if self._closed:
                return
            self._closed = True  # first: from here only EXTINGUISH and DISARM go out
        try:
            self.extinguish()
        finally:
            self.link.close()
