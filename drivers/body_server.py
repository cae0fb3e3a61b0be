"""Robot side of the zenoh body protocol, shared by the bench server and the Spot bridge.

`BodyServer` owns everything protocol-shaped (keys, codec, lease, E-stop keep-alive, state
stream, counters); a `BodyBackend` owns the body (the simulator, or Spot through its SDK).
One loop thread at the state rate polls the backend, enforces the keep-alive and the lease TTL
and publishes state; queries are answered on zenoh's threads under one lock and never wait
on the body (a move is acknowledged at once, its end reported on `feedback` and in `state`).
"""

from __future__ import annotations

import abc
import collections
import logging
import secrets
import threading
import time
from dataclasses import dataclass, field

from capm_field.geometry import SE2
from drivers.body_protocol import (
    QUERIES,
    Keys,
    LinkConfig,
    ProtocolError,
    close_at_interpreter_exit,
    decode,
    encode,
    link_security,
    one_line,
    pose_map,
)
from drivers.interfaces import EStopActive

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MoveStatus:
    """Outcome of one move: status is 'running' | 'succeeded' | 'failed' | 'stopped' | 'estop' | 'timeout'."""

    cmd_id: int
    status: str
    reason: str | None = None
    final: SE2 | None = None

    @property
    def done(self) -> bool:
        return self.status != "running"


@dataclass(frozen=True)
class BackendState:
    pose: SE2
    moving: bool
    powered: bool
    estop: bool
    estop_reason: str | None
    odometry_m: float
    moves: int
    fault: str | None = None
    move: MoveStatus | None = None  # the latest move, by the server's cmd_id


class BodyBackend(abc.ABC):
    """What the server needs from a body. Methods are called under the server lock and must
    return quickly (a backend talking to hardware keeps its own threads)."""

    @abc.abstractmethod
    def poll(self) -> BackendState: ...

    @abc.abstractmethod
    def start_move(self, cmd_id: int, goal: SE2, timeout_s: float) -> None:
        """Start a move; raise EStopActive if E-stopped. Other failures end the move (status)."""

    @abc.abstractmethod
    def stop(self, reason: str) -> None: ...

    @abc.abstractmethod
    def set_power(self, on: bool) -> None: ...

    @abc.abstractmethod
    def keepalive(self, ok: bool, reason: str = "estop_keepalive_timeout") -> None:
        """E-stop keep-alive: False when check-ins stopped (stop + engage, `reason`), True when they resume."""

    def responsive(self) -> bool:
        """False while the backend simulates a frozen robot side (no answers, no state)."""
        return True

    def close(self) -> None:  # noqa: B027 - default: nothing to release
        pass


@dataclass(frozen=True)
class ServerConfig:
    robot_id: str = "spot"
    link: LinkConfig = field(default_factory=lambda: LinkConfig(listen=("tcp/127.0.0.1:7447",)))
    state_rate_hz: float = 100.0  # ≥ 50 Hz required; 100 Hz leaves room for scheduling jitter
    estop_timeout_s: float = 1.0  # no check-in for this long → body stopped, E-stop engaged
    lease_ttl_s: float = 2.0
    max_move_timeout_s: float = 600.0
    # Serving a non-loopback endpoint needs authentication (mutual TLS or user/password) and an
    # access-control list with default deny in the zenoh config (docs/security.md), unless this is set.
    allow_insecure: bool = False


class InsecureLink(ValueError):
    """The robot side was asked to serve beyond loopback without authentication and an ACL."""


def check_link_security(sec: dict, allow_insecure: bool = False) -> None:
    """Raise InsecureLink unless the robot side listens on loopback only, or peers must
    authenticate (mutual TLS on tls/ endpoints, or user/password) and an access-control list with
    default deny is on. `sec` is `link_security(zenoh_config)`. With `allow_insecure`: a warning."""
    authenticated = (sec["tls"] and sec["mtls"]) or sec["usrpwd"]
    if sec["loopback_only"] or (authenticated and sec["acl"]):
        if not sec["loopback_only"] and not sec["tls"]:
            log.warning("body link: user/password without TLS: traffic is neither encrypted nor integrity-protected")
        log.info("body link security: %s", {k: v for k, v in sec.items() if k != "endpoints"})
        return
    missing = [n for n, ok in (("mutual TLS (tls/ endpoints, enable_mtls) or user/password", authenticated),
                               ("access_control with default_permission deny", sec["acl"])) if not ok]
    msg = (f"refusing to serve {', '.join(sec['endpoints'])} without {' and '.join(missing)} "
           "(zenoh config file: see mission/examples/zenoh-robot.json5 and docs/security.md)")
    if not allow_insecure:
        raise InsecureLink(msg)
    log.warning("INSECURE body link (allow_insecure): %s", msg)


class BodyServer:
    """Serve one body on zenoh. `start()` then `close()` (idempotent); also a context manager."""

    def __init__(self, backend: BodyBackend, config: ServerConfig) -> None:
        self.backend, self.config = backend, config
        self.keys = Keys(config.robot_id)
        self._stats: collections.Counter[str] = collections.Counter()
        self._lock = threading.RLock()
        self._session = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._next_cmd = 1
        self._lease: tuple[str, str, int] | None = None  # (client, token, expires monotonic ns)
        self._holder_checks_in_with_token = False  # the holder has sent its token in a CheckIn under this lease
        self._checkins: dict[str, int] = {}  # client -> monotonic ns of its last check-in
        self._engaged_by: set[str] = set()  # clients whose CheckIn engage=true holds the E-stop (latched)
        self._live_clients: set[str] = set()  # clients whose P/client/<client> token is present
        self._keepalive_ok: bool | None = None
        self._last_move: tuple[int, str] | None = None
        self._last_fb_id = 0  # highest cmd_id whose end was published on feedback
        self._pending_fb: list[dict] = []  # ends found while answering a query, published by the loop
        self._seq = 0
        self._peers: dict[str, dict] = {}
        self.security: dict | None = None

    # ---- lifecycle ---------------------------------------------------------------------------
    def start(self) -> "BodyServer":
        import zenoh

        self.backend.keepalive(False, "no_estop_checkin")  # E-stopped until a client checks in (as Spot without an endpoint)
        self._keepalive_ok = False
        zcfg = self.config.link.zenoh_config()
        self.security = sec = link_security(zcfg)
        check_link_security(sec, self.config.allow_insecure)
        s = self._session = zenoh.open(zcfg)
        close_at_interpreter_exit(self)
        try:
            # Who opened a link, as the transport authenticated it (certificate CN under TLS):
            # an audit trail, and the stats show peers that got that far.
            self._link_listener = s.info.declare_link_events_listener(self._on_link, history=True)
            self._state_pub = s.declare_publisher(
                self.keys.state, congestion_control=zenoh.CongestionControl.DROP, express=True
            )
            self._feedback_pub = s.declare_publisher(
                self.keys.feedback, congestion_control=zenoh.CongestionControl.BLOCK, express=True
            )
            # One queryable for the whole prefix so that unknown keys are seen, refused and counted.
            self._queryable = s.declare_queryable(self.keys.all, self._on_query)
            self._puts = s.declare_subscriber(self.keys.all, self._on_put, allowed_origin=zenoh.Locality.REMOTE)
            self._clients = s.liveliness().declare_subscriber(self.keys.clients, self._on_client, history=True)
            self._thread = threading.Thread(target=self._loop, name=f"body-server-{self.config.robot_id}", daemon=True)
            self._thread.start()
            self._token = s.liveliness().declare_token(self.keys.alive)  # last: alive means ready
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        s, self._session = self._session, None
        if s is not None:
            try:
                s.close()
            except Exception:  # noqa: BLE001 - closing must not raise
                pass
        try:
            self.backend.stop("server_closed")
        except Exception:  # noqa: BLE001
            pass

    def __enter__(self) -> "BodyServer":
        return self.start() if self._session is None else self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def stats(self) -> dict[str, int]:
        """Counters: queries by kind, refusals by reason (malformed, bad_version, foreign_key,
        no_lease, lease_refused, estop), estop_timeouts, lease_expired, checkin_not_holder (check-ins
        under the lease holder's id without its token), state_published,
        links_opened / links_closed / links_unnamed (zenoh links; a peer refused by TLS or
        user/password never opens one; one refused by the ACL opens one, its messages are dropped
        by zenoh before this code sees them)."""
        with self._lock:
            return dict(self._stats)

    @property
    def peers(self) -> dict[str, dict]:
        """Open links by remote zenoh id: {'remote': locator, 'auth': certificate CN or None}."""
        with self._lock:
            return {z: dict(v) for z, v in self._peers.items()}

    @property
    def lease_holder(self) -> str | None:
        return self._lease[0] if self._lease else None

    # ---- the loop ----------------------------------------------------------------------------
    def _loop(self) -> None:
        period_ns = int(1e9 / self.config.state_rate_hz)
        next_ns = time.monotonic_ns()
        while not self._stop.is_set():
            try:
                if self.backend.responsive():
                    self._tick()
            except Exception:  # noqa: BLE001 - the loop must survive a bad tick; it is logged
                log.exception("body server tick failed")
            next_ns += period_ns
            now = time.monotonic_ns()
            if next_ns < now - period_ns:  # fell behind (CPU starved): do not burst to catch up
                next_ns = now
            self._stop.wait(max(0.0, (next_ns - now) * 1e-9))

    def _keepalive_fresh(self, now: int) -> bool:
        """Whether the E-stop keep-alive holds: while a lease is held, the holder's own check-ins
        count (another client's must not keep a silent commander's body moving); without a lease,
        anybody's (nobody can move the body then)."""
        if self._lease is not None:
            last = self._checkins.get(self._lease[0])
        else:
            last = max(self._checkins.values(), default=None)
        return last is not None and now - last <= self.config.estop_timeout_s * 1e9

    def _enforce_deadlines(self, now: int) -> None:
        """The lease's expiry and the E-stop keep-alive's timeout, at every loop tick and before any
        query is answered (a query arriving between ticks must not find an expired lease or a lapsed
        keep-alive still honoured). Under the lock."""
        if self._lease is not None and now > self._lease[2]:
            self._stats["lease_expired"] += 1
            self._drop_lease("lease_expired")
        if self._keepalive_ok and not self._keepalive_fresh(now):
            self._keepalive_ok = False
            self._stats["estop_timeouts"] += 1
            self.backend.keepalive(False)

    def _tick(self) -> None:
        now = time.monotonic_ns()
        with self._lock:
            self._enforce_deadlines(now)
            if len(self._checkins) > 64:  # stale ids no longer matter: bounded memory whatever ids clients send
                old = now - 2 * self.config.estop_timeout_s * 1e9
                self._checkins = {c: t for c, t in self._checkins.items() if t >= old}
            st = self.backend.poll()
            self._seq += 1
            holder = self.lease_holder
            m = st.move
            fbs, self._pending_fb = self._pending_fb, []
            if m is not None and (m.cmd_id, m.status) != self._last_move:
                self._last_move = (m.cmd_id, m.status)
                if m.done and m.cmd_id > self._last_fb_id:
                    fbs.append(self._end_feedback(now, m.cmd_id, m.status, m.reason, m.final or st.pose))
        for fb in fbs:
            self._feedback_pub.put(encode("feedback", fb))
        msg = {
            "t_ns": now, "seq": self._seq, "pose": pose_map(*st.pose.as_tuple()), "moving": st.moving,
            "powered": st.powered, "estop": st.estop, "estop_reason": st.estop_reason,
            "odometry_m": float(st.odometry_m), "moves": st.moves, "fault": st.fault,
            "cmd": None if m is None else {"id": m.cmd_id, "status": m.status, "reason": m.reason},
            "lease_holder": holder,
        }
        self._state_pub.put(encode("state", msg))
        self._stats["state_published"] += 1

    def _end_feedback(self, now: int, cmd_id: int, status: str, reason: str | None, pose: SE2) -> dict:
        # every move's end is published once (cmd_ids increase and a move ends before the next starts)
        self._last_fb_id = max(self._last_fb_id, cmd_id)
        return {"t_ns": now, "cmd_id": cmd_id, "status": status, "reason": reason, "pose": pose_map(*pose.as_tuple())}

    def _drop_lease(self, reason: str) -> None:
        # Losing the commander (lease expired, released or its session gone) stops the body.
        self._lease = None
        self._holder_checks_in_with_token = False
        self.backend.stop(reason)

    # ---- queries -----------------------------------------------------------------------------
    def _on_query(self, query) -> None:
        if not self.backend.responsive():
            return  # frozen: no answer, as a hung robot side (the client's get times out)
        key = str(query.key_expr)
        rel = self.keys.relative(key)
        kind = QUERIES.get(rel or "")
        try:
            if kind is None:  # unknown key, or a wildcard query trying to hit several commands
                raise ProtocolError("foreign_key", f"no command at {key!r}")
            raw = query.payload.to_bytes() if query.payload is not None else None
            msg = decode(kind, raw)
            with self._lock:
                self._stats[f"q_{kind}"] += 1
                self._enforce_deadlines(time.monotonic_ns())
                reply = getattr(self, f"_do_{kind}")(msg)
            query.reply(key, encode("ack", {"ok": True, **reply}))
        except ProtocolError as e:
            with self._lock:
                self._stats[e.tag] += 1
            self._reply_error(query, e.tag, e.detail)
        except Exception as e:  # noqa: BLE001 - a backend failure must still answer the client
            log.exception("query %s failed", key)
            with self._lock:
                self._stats["internal"] += 1
            self._reply_error(query, "internal", str(e))

    @staticmethod
    def _reply_error(query, tag: str, detail: str) -> None:
        """The one reply of a refused query: an Error map whose detail (built from the peer's key,
        ids, values) is cut to one line of ≤ TEXT_MAX characters, so the reply is always valid."""
        try:
            query.reply_err(encode("error", {"ok": False, "error": tag, "detail": one_line(detail)}))
        except Exception:  # noqa: BLE001 - zenoh refusing the reply (session closing) must not kill its thread
            log.exception("could not send the %s error reply", tag)

    def _require_lease(self, msg: dict) -> None:
        lease = self._lease
        if lease is None or lease[0] != msg["client"] or lease[1] != msg["lease"]:
            if lease is None:
                who = "nobody holds it"
            elif lease[0] == msg["client"]:
                who = "the token does not match: it was granted to another session of that client id"
            else:
                who = f"held by {lease[0]!r}"
            raise ProtocolError("no_lease", f"client {msg['client']!r} does not hold the body lease ({who})")

    def _do_move(self, msg: dict) -> dict:
        # the message is checked whole before who sends it: a malformed Move is 'malformed' for anyone
        if msg["timeout_ns"] <= 0:
            raise ProtocolError("malformed", "timeout_ns must be > 0")
        self._require_lease(msg)
        g = msg["goal"]
        timeout_s = min(msg["timeout_ns"] * 1e-9, self.config.max_move_timeout_s)
        before = self.backend.poll()
        cmd_id = self._next_cmd
        try:
            self.backend.start_move(cmd_id, SE2(float(g["x"]), float(g["y"]), float(g["yaw"])), timeout_s)
        except EStopActive as e:
            raise ProtocolError("estop", str(e)) from None
        self._next_cmd += 1
        prev = before.move
        if prev is not None and prev.cmd_id > self._last_fb_id:
            # the previous move ends here if it was still running (preempted), or ended since the
            # last loop tick (a Stop just before): its end must still be published once
            now = time.monotonic_ns()
            if prev.done:
                self._pending_fb.append(self._end_feedback(now, prev.cmd_id, prev.status, prev.reason, prev.final or before.pose))
            else:
                self._pending_fb.append(self._end_feedback(now, prev.cmd_id, "stopped", "preempted", before.pose))
        return {"cmd_id": cmd_id}

    def _do_stop(self, msg: dict) -> dict:
        # Stopping is always allowed, lease or not: it can only make the body safer.
        self.backend.stop("stop_requested")
        return {}

    def _do_power(self, msg: dict) -> dict:
        self._require_lease(msg)
        self.backend.set_power(bool(msg["on"]))
        return {}

    def _do_lease_acquire(self, msg: dict) -> dict:
        now, ttl = time.monotonic_ns(), int(self.config.lease_ttl_s * 1e9)
        lease = self._lease
        if lease is not None and lease[0] != msg["client"]:
            raise ProtocolError(
                "lease_refused", f"body lease held by {lease[0]!r} (expires in {(lease[2] - now) * 1e-9:.1f} s unless refreshed)"
            )
        if lease is not None and msg.get("lease") != lease[1]:
            # a refresh must show the token: the client id alone (visible to every observer in
            # State.lease_holder) must not hand the lease to another session
            raise ProtocolError(
                "lease_refused", f"body lease held by {lease[0]!r} under another token (a refresh needs the "
                f"token it was granted; expires in {(lease[2] - now) * 1e-9:.1f} s unless refreshed)"
            )
        token = lease[1] if lease is not None else secrets.token_hex(8)
        if lease is None:
            self._holder_checks_in_with_token = False  # a new lease: its holder has not checked in with it yet
        self._lease = (msg["client"], token, now + ttl)
        if lease is None and msg["client"] not in self._live_clients:
            self._stats["lease_without_token"] += 1  # no P/client token: losing this commander is seen by the keep-alive only
        return {"lease": token, "ttl_ns": ttl}

    def _do_lease_release(self, msg: dict) -> dict:
        self._require_lease(msg)
        self._drop_lease("lease_released")
        return {}

    def _holder_session(self, client: str, token: str | None) -> bool:
        """Whether a CheckIn may count as `client`'s: any client's, except under the lease holder's id
        (public in State.lease_holder), where it must carry the holder's token, or no token from a
        holder that has never sent one in this lease (clients written before CheckIn's `lease`).
        A CheckIn with the token also records that the holder sends it (from then on it must)."""
        lease = self._lease
        if lease is None or client != lease[0]:
            return True
        if token == lease[1]:
            self._holder_checks_in_with_token = True
            return True
        return token is None and not self._holder_checks_in_with_token

    def _do_checkin(self, msg: dict) -> dict:
        now, client, engage = time.monotonic_ns(), msg["client"], msg.get("engage")
        if engage is True:
            # a client asserts the E-stop (Spot's settle_then_cut): latched until every client that
            # engaged it has sent engage=false (or its session is gone); plain check-ins keep it.
            # Anybody may stop the body: applied before (and whatever) the session check below
            self._engaged_by.add(client)
            self._keepalive_ok = False
            self.backend.keepalive(False, "estop_engaged_by_client")
        if not self._holder_session(client, msg.get("lease")):
            # another session under the holder's id (a second process started with the same id):
            # it must not keep a silent commander's keep-alive fresh, nor release its engage
            self._stats["checkin_not_holder"] += 1
            if engage is True:
                return {"timeout_ns": int(self.config.estop_timeout_s * 1e9), "estop": self.backend.poll().estop}
            raise ProtocolError("no_lease", f"CheckIn under the lease holder's id {client!r} without its lease token: "
                                            "not counted for its E-stop keep-alive")
        self._checkins[client] = now
        if engage is False and self._engaged_by:
            self._engaged_by = {c for c in self._engaged_by if c != client and c in self._live_clients}
            if self._engaged_by:
                raise ProtocolError("estop", f"the E-stop is also engaged by {', '.join(sorted(self._engaged_by))}, "
                                             "whose session is open: only it can release its engage")
        if not self._engaged_by and not self._keepalive_ok and self._keepalive_fresh(now):
            self._keepalive_ok = True
            self.backend.keepalive(True)
        st = self.backend.poll()
        return {"timeout_ns": int(self.config.estop_timeout_s * 1e9), "estop": st.estop}

    # ---- links, puts and client liveliness ----------------------------------------------------
    def _on_link(self, event) -> None:
        import zenoh

        link = event.link
        zid, remote, auth = str(link.zid), str(link.dst), link.auth_identifier
        with self._lock:
            if event.kind == zenoh.SampleKind.PUT:
                self._stats["links_opened"] += 1
                if auth is None:
                    self._stats["links_unnamed"] += 1  # plain tcp/, or user/password (not shown per link)
                self._peers[zid] = {"remote": remote, "auth": auth}
            else:
                self._stats["links_closed"] += 1
                self._peers.pop(zid, None)
        log.info("body link %s: peer %s from %s, authenticated as %s",
                 "opened" if event.kind == zenoh.SampleKind.PUT else "closed", zid, remote, auth)

    def _on_put(self, sample) -> None:
        with self._lock:
            self._stats["foreign_put"] += 1  # nobody but this server publishes under the prefix

    def _on_client(self, sample) -> None:
        import zenoh

        client = str(sample.key_expr).rsplit("/", 1)[-1]
        if sample.kind != zenoh.SampleKind.DELETE:
            with self._lock:
                self._live_clients.add(client)
            return
        with self._lock:
            self._live_clients.discard(client)
            self._checkins.pop(client, None)  # a later session with this id starts afresh
            if self._lease is not None and self._lease[0] == client:
                self._stats["commander_lost"] += 1
                self._drop_lease("commander_lost")
