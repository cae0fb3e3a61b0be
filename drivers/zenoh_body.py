"""`ZenohBody`: the `Body` driver over the zenoh body protocol (docs/protocols/body-zenoh.md).

Same adapter on the robot (against `capm-field spot-bridge`) and on the wire-level bench
(against `sim_bench.zenoh_body_server`). Background work that must not depend on the caller
(E-stop check-ins, lease refresh) runs on one thread; state, feedback and the robot's
liveliness token arrive on zenoh callbacks. Link loss is latched: once the robot side is
gone (liveliness DELETE) or silent (no state for `state_stale_s`), every call raises
`LinkLost`, check-ins stop (so a robot side that comes back stops on its own keep-alive
timeout), and a new `ZenohBody` is needed to reconnect.
"""

from __future__ import annotations

import collections
import logging
import math
import os
import secrets
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

from capm_field.geometry import SE2
from drivers.body_protocol import (
    GOAL_EXTENT_M,
    Keys,
    LinkConfig,
    ProtocolError,
    close_at_interpreter_exit,
    decode,
    encode,
    is_loopback_endpoint,
    link_security,
    pose_map,
)
from drivers.host_stall import host_clock
from drivers.interfaces import (
    Body,
    BodyState,
    DriverError,
    DriverTimeout,
    EStopActive,
    LeaseRefused,
    LinkLost,
    MoveResult,
    StateCallback,
    StateNotifier,
)

log = logging.getLogger(__name__)
_TERMINAL = ("succeeded", "failed", "stopped", "estop", "timeout")
# Ack fields each request needs back (optional in the Ack schema, required for that request)
_ACK_FIELDS = {"move": ("cmd_id",), "lease_acquire": ("lease", "ttl_ns"), "checkin": ("timeout_ns", "estop")}
_MAX_NS = 2**64 - 1  # a CBOR uint
SEQ_RESTART_GAP = 1000  # State.seq this far below the last one taken: the robot side restarted (10 s of states)
SEQ_RESTART_QUIET_NS = 500_000_000  # or no State taken for this long (a restart takes longer)
# A State older than this is reported as the fault "state_stale" (not latched; link loss comes at
# `state_stale_s`): the ignition interlock denies on it, as on a CAN arm state as old (CanArm),
# instead of flaming on the last pose for the half lease a frozen robot side takes to be LinkLost.
STATE_FRESH_S = 0.25
REFRESH_RETRY_S = 0.02  # lease refreshes at most this often (a failing refresh must not spin; a TTL under 80 ms is refreshed this often)


@dataclass(frozen=True)
class ZenohBodyConfig:
    robot_id: str = "spot"
    link: LinkConfig = field(default_factory=lambda: LinkConfig(connect=("tcp/127.0.0.1:7447",)))
    connect_timeout_s: float = 5.0  # robot's liveliness token + first state must arrive by then
    query_timeout_s: float = 0.5  # per command query: the robot acknowledges at once
    state_stale_s: float | None = None  # no state this long → LinkLost; default: half the transport lease
    client_id: str | None = None  # default: unique per instance

    @staticmethod
    def loopback(port: int, robot_id: str = "spot", lease_ms: int = 1000, *, config_file: str | None = None,
                 proto: str = "tcp", **kw) -> "ZenohBodyConfig":
        link = LinkConfig(connect=(f"{proto}/127.0.0.1:{port}",), lease_ms=lease_ms, config_file=config_file)
        return ZenohBodyConfig(robot_id=robot_id, link=link, **kw)

    @staticmethod
    def from_spec(spec, base_dir: str | os.PathLike | None = None, **kw) -> "ZenohBodyConfig":
        """From a mission file's `drivers.zenoh` (`mission.config.ZenohSpec`): robot_id, connect,
        listen, `lease_s` (transport lease) and `config_file` (TLS/auth JSON5, relative to
        `base_dir`, the mission file's directory)."""
        cf = spec.config_file
        if cf and base_dir is not None and not Path(cf).expanduser().is_absolute():
            cf = str(Path(base_dir) / cf)
        link = LinkConfig(connect=tuple(spec.connect), listen=tuple(spec.listen), lease_ms=int(round(spec.lease_s * 1000)),
                          config_file=cf)
        return ZenohBodyConfig(robot_id=spec.robot_id, link=link, **kw)


def _local_timeout(err) -> bool:
    """zenoh's local error reply to a query held unanswered past its timeout: payload b"Timeout"
    (encoding zenoh/string or zenoh/bytes, seen both); never a robot side's error, which is a CBOR
    map (those bytes are a truncated CBOR byte string)."""
    try:
        return err.payload.to_bytes() == b"Timeout"
    except Exception:  # noqa: BLE001 - anything else is the robot's reply, decoded as such
        return False


class ZenohBody(Body):
    def __init__(self, config: ZenohBodyConfig | None = None) -> None:
        import zenoh

        cfg = config or ZenohBodyConfig()
        if cfg.client_id is None:
            cfg = replace(cfg, client_id=f"c{os.getpid()}-{secrets.token_hex(4)}")
        self.config = cfg
        self.keys = Keys(cfg.robot_id)
        self.client_id: str = cfg.client_id  # type: ignore[assignment]
        self._stale_ns = int((cfg.state_stale_s if cfg.state_stale_s is not None else cfg.link.lease_ms / 2000) * 1e9)
        self._host = host_clock()
        self._cond = threading.Condition()
        self._state: dict | None = None
        self._state_rx_ns = 0
        self._alive = False
        self._lost: str | None = None
        self._closed = False
        self._results: collections.OrderedDict[int, dict] = collections.OrderedDict()
        self._lease: str | None = None
        self._lease_ttl_ns = 0
        self._lease_refreshed_ns = 0
        self._checkin_period_s = 0.25
        self._seq = 0
        self.stats: collections.Counter[str] = collections.Counter()
        self._listeners: list[Callable[[BodyState], None]] = []
        self._last_seq: int | None = None  # State.seq of the last state taken: older ones are dropped
        self._stop_bg = threading.Event()
        self._bg_kick = threading.Event()  # set on close and on a new lease: the background loop re-plans its wait
        self._bg: threading.Thread | None = None
        zcfg = cfg.link.zenoh_config()
        sec = link_security(zcfg)
        if not sec["tls"] and any(not is_loopback_endpoint(e) for e in cfg.link.connect):
            log.warning("body link to %s without TLS: anyone on the network can read and forge it (docs/security.md)",
                        ", ".join(cfg.link.connect))
        self._session = zenoh.open(zcfg)
        close_at_interpreter_exit(self)
        try:
            s = self._session
            self._token = s.liveliness().declare_token(self.keys.client(self.client_id))
            self._subs = [
                s.declare_subscriber(self.keys.state, self._on_state),
                s.declare_subscriber(self.keys.feedback, self._on_feedback),
                s.liveliness().declare_subscriber(self.keys.alive, self._on_alive, history=True),
            ]
            self._wait_connected(cfg.connect_timeout_s)
            ack = self._checkin(time.monotonic() + cfg.connect_timeout_s)  # releases the robot's E-stop
            self._wait_connected(cfg.connect_timeout_s, after_ns=time.monotonic_ns())  # a state that shows it
            self._wait_estop_shown(bool(ack.get("estop")), cfg.connect_timeout_s)
            self._bg = threading.Thread(target=self._background, name=f"zenoh-body-{self.client_id}", daemon=True)
            self._bg.start()
        except BaseException:
            self.close()
            raise

    # ---- Body --------------------------------------------------------------------------------
    def move_to(self, goal: SE2, timeout: float, on_state: StateCallback | None = None) -> MoveResult:
        if not all(math.isfinite(v) for v in goal.as_tuple()) or max(abs(goal.x), abs(goal.y)) > GOAL_EXTENT_M:
            raise ValueError(f"goal must be finite and within ±{GOAL_EXTENT_M:.0f} m, got {goal}")
        if not timeout > 0:  # NaN too
            raise ValueError(f"timeout must be > 0 s, got {timeout}")
        t0 = time.monotonic()
        deadline = t0 + timeout
        self._ensure_lease(deadline)
        odo0 = self._state["odometry_m"] if self._state else 0.0
        msg = {"client": self.client_id, "lease": self._lease or "", "goal": pose_map(*goal.as_tuple()),
               "timeout_ns": max(1, int(min(timeout * 1e9, _MAX_NS)))}
        try:
            ack = self._query(self.keys.cmd_move, "move", msg, deadline)
        except LeaseRefused:
            self._lease = None  # the robot forgot us (expired, or its side restarted)
            raise
        cmd_id = ack.get("cmd_id")
        if not isinstance(cmd_id, int):
            raise DriverError(f"robot acknowledged the move without a cmd_id: {ack}")
        notify = StateNotifier(on_state)
        seen_rx = 0  # stamp of the last state handed to on_state (called outside the lock)
        while True:
            with self._cond:
                res = self._results.get(cmd_id)
                if res is None:
                    cur = (self._state or {}).get("cmd") or {}
                    if isinstance(cur.get("id"), int) and cur["id"] > cmd_id:
                        res = {"status": "stopped", "reason": "preempted", "pose": self._state["pose"]}
                if res is not None:
                    break
                err = self._link_error()
                if err:
                    self._stop_nowait()
                    raise LinkLost(f"link to {self.keys.prefix} lost during move {cmd_id}: {err}")
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._cond.wait(min(remaining, 0.02))
                fresh = on_state is not None and self._state is not None and self._state_rx_ns != seen_rx
                if fresh:
                    seen_rx = self._state_rx_ns
            if fresh:
                try:
                    st = self.state()
                except DriverError:  # the next pass of the loop finds the link error and stops the body
                    st = None
                if st is not None:
                    notify(st)
        if res is None:
            self.stop()
            raise DriverTimeout(f"move {cmd_id} to {goal} not done within {timeout} s (body stopped)")
        p = res["pose"]
        final = SE2(p["x"], p["y"], p["yaw"])
        extra = {"cmd_id": cmd_id, "duration_s": time.monotonic() - t0,
                 "distance_m": ((self._state or {}).get("odometry_m", odo0)) - odo0}
        status = res["status"]
        if status == "estop":
            raise EStopActive(f"E-stop engaged during move {cmd_id} ({res.get('reason')})")
        if status == "timeout":
            raise DriverTimeout(f"move {cmd_id} hit its deadline on the robot side (body stopped)")
        return MoveResult(ok=status == "succeeded", reason=res.get("reason"), final=final, extra=extra)

    def stop(self) -> None:
        """Best effort, never raises: the robot side also stops on its own when we go silent."""
        try:
            if self._session is not None and not self._closed:
                self._query(self.keys.cmd_stop, "stop", {"client": self.client_id},
                            time.monotonic() + self.config.query_timeout_s, check_link=False)
        except Exception:  # noqa: BLE001 - stop() does not raise (interface contract)
            self.stats["stop_failed"] += 1

    def state(self) -> BodyState:
        with self._cond:
            m, rx, err = self._state, self._state_rx_ns, self._link_error()
        if m is None:
            raise LinkLost(f"no state from {self.keys.prefix}")
        p = m["pose"]
        if err:
            fault = f"link_lost: {err}"
        elif time.monotonic_ns() - rx > STATE_FRESH_S * 1e9:
            fault = "state_stale"  # where the body is and whether it moves is not known now
        else:
            fault = m.get("fault")
        return BodyState(
            pose=SE2(p["x"], p["y"], p["yaw"]), moving=m["moving"], powered=m["powered"], estop=m["estop"],
            stamp_ns=rx,  # local monotonic receive time: the robot's clock is another machine's
            odometry_m=m["odometry_m"], fault=fault,
        )

    # ---- extras (not in the Body interface) --------------------------------------------------
    def acquire_lease(self, timeout: float = 1.0) -> None:
        self._ensure_lease(time.monotonic() + timeout)

    def release_lease(self, timeout: float = 0.5) -> None:
        lease, self._lease = self._lease, None
        if lease:
            self._query(self.keys.lease_release, "lease_release", {"client": self.client_id, "lease": lease},
                        time.monotonic() + timeout, check_link=False)

    def set_power(self, on: bool, timeout: float = 1.0) -> None:
        deadline = time.monotonic() + timeout
        self._ensure_lease(deadline)
        self._query(self.keys.cmd_power, "power", {"client": self.client_id, "lease": self._lease or "", "on": on}, deadline)

    def engage_estop(self, timeout: float = 0.5) -> None:
        """Assert the E-stop now (Spot's settle_then_cut). It stays engaged, through this client's
        own periodic check-ins, until `release_estop()` (or this session ends)."""
        self._query(self.keys.estop_checkin, "checkin", self._checkin_msg(engage=True), time.monotonic() + timeout)

    def release_estop(self, timeout: float = 0.5) -> bool:
        """Release this client's engage; True when the body is free to move (no other engage,
        keep-alive fresh). Raises EStopActive while another open session's engage holds it."""
        ack = self._query(self.keys.estop_checkin, "checkin", self._checkin_msg(engage=False), time.monotonic() + timeout)
        return not ack["estop"]

    def ping(self, timeout: float = 0.5) -> float:
        """One E-stop check-in round trip (s): a harmless command for link figures."""
        t = time.perf_counter()
        self._checkin(time.monotonic() + timeout)
        return time.perf_counter() - t

    def add_state_listener(self, fn: Callable[[BodyState], None]) -> None:
        """Call `fn(state)` on zenoh's thread for every state received (keep it short)."""
        self._listeners.append(fn)

    @property
    def link_lost(self) -> str | None:
        with self._cond:
            return self._link_error()

    def close(self) -> None:
        with self._cond:
            if self._closed:
                return
            link_ok = self._link_error() is None
            # first: from here every command query (lease_acquire, move, power …) of another thread
            # is LinkLost; without it a move_to between the lease release below and the end of
            # close() acquired a new lease and walked the body after close() (session 49)
            self._closed = True
        self._stop_bg.set()
        self._bg_kick.set()
        if self._bg is not None and self._bg is not threading.current_thread():
            self._bg.join(timeout=2.0)
        if self._lease and link_ok:
            try:
                self.release_lease(timeout=0.2)  # the robot stops the body when the lease goes
            except Exception:  # noqa: BLE001 - closing must go on
                pass
        s, self._session = self._session, None
        if s is not None:
            try:
                s.close()  # also ends the callback threads: no hang at interpreter exit
            except Exception:  # noqa: BLE001
                pass
        with self._cond:
            self._cond.notify_all()

    # ---- wire --------------------------------------------------------------------------------
    def _next_seq(self) -> int:
        self._seq += 1
        return self._seq

    def _query(self, key: str, kind: str, msg: dict, deadline: float, check_link: bool = True) -> dict:
        if check_link:
            with self._cond:
                err = self._link_error()
            if err:
                raise LinkLost(f"link to {self.keys.prefix} lost: {err}")
        t = max(0.001, min(self.config.query_timeout_s, deadline - time.monotonic()))
        replies = self._session.get(key, payload=encode(kind, msg), timeout=t)
        for reply in replies:  # first reply only: one robot side per key
            if reply.ok is not None:
                return self._ack(key, kind, reply.ok.payload.to_bytes())
            if _local_timeout(reply.err):
                break  # zenoh's own reply to a query nobody answered in time (a frozen robot side)
            try:
                e = decode("error", reply.err.payload.to_bytes())
            except ProtocolError as pe:
                self.stats["bad_reply"] += 1
                raise DriverError(f"robot side sent an unreadable error for {key}: {pe}") from None
            tag, detail = e["error"], e["detail"]
            self.stats[f"refused_{tag}"] += 1
            if tag == "estop":
                raise EStopActive(detail)
            if tag in ("no_lease", "lease_refused"):
                raise LeaseRefused(detail)
            raise DriverError(f"robot side refused {key}: {tag}: {detail}")
        with self._cond:
            err = self._link_error()
        if err:
            raise LinkLost(f"link to {self.keys.prefix} lost: {err}")
        raise DriverTimeout(f"no answer to {key} within {t:.3f} s")

    def _ack(self, key: str, kind: str, raw: bytes) -> dict:
        """A success reply, checked: an Ack map with ok = true and the fields `kind` needs back; a
        reply that is not (another robot side's version, a foreign queryable) is a DriverError."""
        try:
            ack = decode("ack", raw)
            missing = [f for f in _ACK_FIELDS.get(kind, ()) if f not in ack]
            if ack["ok"] is not True or missing:
                raise ProtocolError("malformed", f"ok={ack['ok']}, missing {missing}" if missing else "ok=false in a success reply")
        except ProtocolError as e:
            self.stats["bad_reply"] += 1
            raise DriverError(f"robot side sent an unusable reply for {key}: {e}") from None
        return ack

    def _stop_nowait(self) -> None:
        try:
            self._session.get(self.keys.cmd_stop, lambda _r: None, payload=encode("stop", {"client": self.client_id}),
                              timeout=0.2)
        except Exception:  # noqa: BLE001 - best effort on a link already known bad
            pass

    def _ensure_lease(self, deadline: float) -> None:
        if self._lease is None:
            self._refresh_lease(deadline)

    def _refresh_lease(self, deadline: float) -> None:
        msg = {"client": self.client_id, "lease": self._lease}
        ack = self._query(self.keys.lease_acquire, "lease_acquire", msg, deadline)
        self._lease, self._lease_ttl_ns = ack["lease"], ack["ttl_ns"]
        self._lease_refreshed_ns = time.monotonic_ns()
        self._bg_kick.set()  # its next refresh may be due before the background loop's next check-in

    def _checkin_msg(self, engage: bool | None = None) -> dict:
        """A CheckIn, with the lease token while this client holds the lease (the robot side counts
        check-ins under the holder's id only with it: another session with our id cannot keep our
        keep-alive fresh)."""
        msg: dict = {"client": self.client_id, "seq": self._next_seq()}
        if engage is not None:
            msg["engage"] = engage
        if self._lease:
            msg["lease"] = self._lease
        return msg

    def _checkin(self, deadline: float) -> dict:
        ack = self._query(self.keys.estop_checkin, "checkin", self._checkin_msg(), deadline)
        # Spot's EstopKeepAlive checks in at a third of the timeout; a quarter leaves one more try.
        # (at least once a second: a robot side announcing an absurd timeout must not stop our check-ins)
        self._checkin_period_s = min(1.0, max(0.02, ack["timeout_ns"] * 1e-9 / 4))
        return ack

    def _wait_estop_shown(self, estop: bool, timeout: float) -> None:
        """Wait (≤ timeout, never raises) for a State whose E-stop flag is the check-in reply's. A
        State received after the reply may still have been read by the robot side before it
        handled the check-in (its loop reads, then publishes): taken as the state at start, it
        showed the E-stop engaged and a mission refused to start on a loaded machine."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._state is not None and bool(self._state["estop"]) != estop and self._lost is None:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    log.warning("no state with estop=%s within %.1f s of the check-in reply", estop, timeout)
                    return
                self._cond.wait(min(remaining, 0.05))

    def _background(self) -> None:
        """Check-ins every `_checkin_period_s`, and lease refreshes every ttl/4 while holding the
        lease (body-zenoh.md), each on its own deadline: a lease TTL shorter than the check-in
        period (both are the robot side's settings) must not expire between check-ins."""
        next_checkin = time.monotonic() + self._checkin_period_s
        refresh_tried = 0.0  # a failed refresh is retried no sooner than REFRESH_RETRY_S later
        while True:
            wake = next_checkin
            if self._lease:
                due = self._lease_refreshed_ns * 1e-9 + max(self._lease_ttl_ns * 1e-9 / 4, REFRESH_RETRY_S)
                wake = min(wake, max(due, refresh_tried + REFRESH_RETRY_S))
            self._bg_kick.wait(max(0.0, wake - time.monotonic()))
            self._bg_kick.clear()
            if self._stop_bg.is_set():
                return
            with self._cond:
                lost = self._link_error()
            if lost:
                return  # latched: stop checking in so a robot side that comes back stops itself
            try:
                if time.monotonic() >= next_checkin:
                    next_checkin += self._checkin_period_s
                    if next_checkin < time.monotonic():
                        next_checkin = time.monotonic()
                    self._checkin(time.monotonic() + self._checkin_period_s)
                    self.stats["checkins"] += 1
                if self._lease and time.monotonic_ns() - self._lease_refreshed_ns >= self._lease_ttl_ns / 4 \
                        and time.monotonic() >= refresh_tried + REFRESH_RETRY_S:
                    refresh_tried = time.monotonic()
                    try:
                        self._refresh_lease(time.monotonic() + min(self._checkin_period_s, self._lease_ttl_ns * 1e-9 / 4))
                    except LeaseRefused:
                        self._lease = None
            except DriverError:
                self.stats["checkin_failed"] += 1
            except Exception:  # noqa: BLE001 - the keep-alive thread must outlive any one bad round
                self.stats["checkin_failed"] += 1
                log.exception("E-stop check-in failed")

    def _link_error(self) -> str | None:
        """Why the link is unusable, or None. Call with `_cond` held. Latches the first reason."""
        if self._lost is None:
            if self._closed:
                return "driver closed"
            # silence counted from the end of a stall of this process, if later (drivers/host_stall.py):
            # a host that did not run for 0.6 s latched the link lost, E-stopping a healthy robot
            if self._state is not None and time.monotonic_ns() - self._host.silent_since(self._state_rx_ns) > self._stale_ns:
                self._lost = f"state stream stalled for {(time.monotonic_ns() - self._state_rx_ns) / 1e6:.0f} ms"
        return self._lost

    def _wait_connected(self, timeout: float, after_ns: int = 0) -> None:
        deadline = time.monotonic() + timeout
        with self._cond:
            while not (self._alive and self._state is not None and self._state_rx_ns > after_ns):
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self._lost:
                    ends = ", ".join(self.config.link.connect) or "(no connect endpoints)"
                    raise LinkLost(
                        f"no robot side for {self.keys.prefix} at {ends} within {timeout} s "
                        f"(liveliness token {'seen' if self._alive else 'missing'}, state {'seen' if self._state else 'missing'})"
                    )
                self._cond.wait(min(remaining, 0.05))

    # ---- callbacks (zenoh threads) -----------------------------------------------------------
    def _on_state(self, sample) -> None:
        try:
            m = decode("state", sample.payload.to_bytes())
        except ProtocolError:
            self.stats["bad_state"] += 1
            return
        now = time.monotonic_ns()
        with self._cond:
            if self._last_seq is not None and m["seq"] <= self._last_seq and not (
                    m["seq"] < self._last_seq - SEQ_RESTART_GAP or now - self._state_rx_ns > SEQ_RESTART_QUIET_NS):
                # seq increases by one per State: an equal or slightly lower one is a replayed or
                # reordered sample (or a second publisher on the key) and would move the pose back
                # in time. A far lower one, or any after a quiet spell, is a restarted robot side
                # (its seq starts again at 0): taken, else its states would be dropped for good
                self.stats["stale_state"] += 1
                return
            self._last_seq = m["seq"]
            self._state, self._state_rx_ns = m, now
            c = m.get("cmd")
            if c and c["status"] in _TERMINAL and c["id"] not in self._results:
                self._remember(c["id"], {"status": c["status"], "reason": c.get("reason"), "pose": m["pose"]})
            self._cond.notify_all()
        if self._listeners:
            st = self.state()
            for fn in self._listeners:
                try:
                    fn(st)
                except Exception:  # noqa: BLE001 - one bad listener must not cost the others their states
                    self.stats["listener_failed"] += 1
                    if self.stats["listener_failed"] == 1:
                        log.exception("state listener %r failed (logged once)", fn)

    def _on_feedback(self, sample) -> None:
        try:
            m = decode("feedback", sample.payload.to_bytes())
        except ProtocolError:
            self.stats["bad_feedback"] += 1
            return
        with self._cond:
            if m["status"] in _TERMINAL:
                self._remember(m["cmd_id"], {"status": m["status"], "reason": m.get("reason"), "pose": m["pose"]})
            self._cond.notify_all()

    def _remember(self, cmd_id: int, res: dict) -> None:
        self._results[cmd_id] = res
        while len(self._results) > 64:
            self._results.popitem(last=False)

    def _on_alive(self, sample) -> None:
        import zenoh

        with self._cond:
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive = True
            elif self._alive or self._state is not None:
                self._alive = False
                if self._lost is None:
                    self._lost = "robot side gone (liveliness token deleted)"
            self._cond.notify_all()
