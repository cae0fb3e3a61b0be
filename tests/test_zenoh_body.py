"""Zenoh body protocol specifics: refusals are counted and never acted on, one commander at
a time, the E-stop keep-alive, a killed or frozen robot side, clean shutdown."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import cbor2
import pytest
import zenoh

from capm_field.config import BodyConfig
from capm_field.geometry import SE2
from drivers.body_protocol import Keys, LinkConfig, decode, encode, pose_map
from drivers.interfaces import LeaseRefused, LinkLost
from drivers.zenoh_body import ZenohBody, ZenohBodyConfig
from sim_bench.zenoh_body_server import free_port, serve_sim_body, spawn_server
from waiting import wait_for

FAST = BodyConfig(max_speed=2.0, max_accel=4.0, max_yaw_rate=3.0)
RID = "proto"


@pytest.fixture
def port() -> int:
    return free_port()


@pytest.fixture
def raw(port):
    """A bare zenoh session on the bench link, for hand-made payloads."""
    holder: dict = {}

    def open_() -> zenoh.Session:
        s = zenoh.open(LinkConfig(connect=(f"tcp/127.0.0.1:{port}",)).zenoh_config())
        holder.setdefault("sessions", []).append(s)
        return s

    yield open_
    for s in holder.get("sessions", []):
        s.close()


def ask(session: zenoh.Session, key: str, payload: bytes | None) -> tuple[bool, dict]:
    """One query; (ok, decoded reply). Waits for the server's liveliness first."""
    assert wait_for(lambda: len(list(session.liveliness().get(f"capm/{RID}/body/alive", timeout=0.5))) > 0)
    for reply in session.get(key, payload=payload, timeout=2.0):
        if reply.ok is not None:
            return True, decode("ack", reply.ok.payload.to_bytes())
        return False, decode("error", reply.err.payload.to_bytes())
    raise AssertionError(f"no reply on {key}")


def _with_key_twice(msg: dict, key: str, value) -> bytes:
    """CBOR of `msg` (< 23 entries) with `key` given once more at the end: not valid CBOR."""
    raw = cbor2.dumps(msg)
    assert 0xa0 <= raw[0] < 0xb7
    return bytes([raw[0] + 1]) + raw[1:] + cbor2.dumps(key) + cbor2.dumps(value)


def test_duplicate_keys_are_malformed_whichever_comes_first():
    from drivers.body_protocol import ProtocolError, decode as decode_msg

    base = {"v": 1, "client": "c1", "seq": 1}
    for first, then in ((False, True), (True, False)):
        payload = _with_key_twice({**base, "engage": first}, "engage", then)
        with pytest.raises(ProtocolError) as e:
            decode_msg("checkin", payload)
        assert e.value.tag == "malformed" and "twice" in e.value.detail
    decode_msg("checkin", cbor2.dumps({**base, "engage": True}))  # the same map without the second key is fine


def test_malformed_payloads_are_refused_and_counted(port, raw):
    k = Keys(RID)
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], body=FAST) as bench:
        s = raw()
        good_goal = {"client": "x", "lease": "nope", "goal": pose_map(1, 0, 0), "timeout_ns": 10**9}
        cases = {
            b"": "malformed",
            b"\xff\x00garbage": "malformed",
            cbor2.dumps([1, 2, 3]): "malformed",
            cbor2.dumps({"v": 1, "client": "x"}): "malformed",
            cbor2.dumps({"v": 1, **good_goal, "goal": {"x": "1", "y": 0, "yaw": 0}}): "malformed",
            cbor2.dumps({"v": 1, **good_goal, "goal": {"x": float("inf"), "y": 0.0, "yaw": 0.0}}): "malformed",
            cbor2.dumps({"v": 1, **good_goal, "timeout_ns": True}): "malformed",
            cbor2.dumps({"v": 99, **good_goal}): "bad_version",
            cbor2.dumps({**good_goal}): "malformed",  # no version
            b"\xa1" + b"\x00" * 5000: "malformed",  # oversize
            # a real no float can hold (CBOR bignum): malformed, not an internal error
            cbor2.dumps({"v": 1, **good_goal, "goal": {"x": 0.0, "y": 0.0, "yaw": 2**1100}}): "malformed",
            _with_key_twice({"v": 1, **good_goal}, "timeout_ns", 1): "malformed",  # RFC 8949 §5.6
        }
        for payload, tag in cases.items():
            ok, rep = ask(s, k.cmd_move, payload)
            assert not ok and rep["error"] == tag, (payload[:20], rep)
        stats = bench.server.stats
        assert stats["malformed"] == 11 and stats["bad_version"] == 1
        assert bench.sim.moves == 0 and not bench.sim.moving


def test_foreign_keys_and_wildcards_are_refused_and_counted(port, raw):
    k = Keys(RID)
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], body=FAST) as bench:
        s = raw()
        payload = encode("stop", {"client": "x"})
        for key in (f"{k.prefix}/cmd/jump", f"{k.prefix}/cmd/*", f"{k.prefix}/**", f"{k.prefix}/state"):
            ok, rep = ask(s, key, payload)
            assert not ok and rep["error"] == "foreign_key", key
        # another robot's prefix never reaches this server
        assert list(s.get("capm/other/body/cmd/move", payload=payload, timeout=0.3)) == []
        s.put(f"{k.prefix}/cmd/move", payload)  # a put instead of a query: counted, ignored
        assert wait_for(lambda: bench.server.stats.get("foreign_put", 0) == 1)
        assert bench.server.stats["foreign_key"] == 4
        assert bench.sim.moves == 0


def test_move_without_the_lease_is_refused(port, raw):
    k = Keys(RID)
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], body=FAST) as bench:
        s = raw()
        ok, rep = ask(s, k.cmd_move, encode("move", {"client": "x", "lease": "forged", "goal": pose_map(1, 0, 0),
                                                     "timeout_ns": 10**9}))
        assert not ok and rep["error"] == "no_lease"
        ok, rep = ask(s, k.cmd_power, encode("power", {"client": "x", "lease": "forged", "on": False}))
        assert not ok and rep["error"] == "no_lease"
        assert bench.server.stats["no_lease"] == 2
        assert bench.sim.moves == 0 and bench.sim.powered


def test_second_commander_is_refused_until_the_first_releases(port):
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], body=FAST) as bench:
        a = ZenohBody(ZenohBodyConfig.loopback(port, RID, client_id="alice"))
        b = ZenohBody(ZenohBodyConfig.loopback(port, RID, client_id="bob"))
        try:
            assert a.move_to(SE2(0.2, 0.0, 0.0), timeout=5.0).ok
            with pytest.raises(LeaseRefused, match="held by 'alice'"):
                b.move_to(SE2(0.0, 0.0, 0.0), timeout=5.0)
            assert bench.server.stats["lease_refused"] == 1
            assert bench.sim.moves == 1
            time.sleep(2.5)  # past the TTL: alice's keep-alive thread refreshes the lease
            with pytest.raises(LeaseRefused):
                b.move_to(SE2(0.0, 0.0, 0.0), timeout=5.0)
            a.close()  # releases the lease
            assert b.move_to(SE2(0.0, 0.0, 0.0), timeout=5.0).ok
        finally:
            a.close()
            b.close()


def test_a_lease_shorter_than_the_checkin_period_is_refreshed_on_its_own_clock(port):
    """Robot side: lease TTL 0.5 s, E-stop timeout 4 s (check-ins every 1 s): the client refreshes
    the lease every ttl/4 (body-zenoh.md), not only when it checks in, so a 3 s walk completes."""
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], lease_ttl_s=0.5, estop_timeout_s=4.0,
                        body=BodyConfig(max_speed=1.0, max_accel=4.0, max_yaw_rate=3.0)) as bench:
        body = ZenohBody(ZenohBodyConfig.loopback(port, RID))
        try:
            assert body._checkin_period_s > 0.5  # the case under test
            r = body.move_to(SE2(3.0, 0.0, 0.0), 10.0)
            assert r.ok, r
            assert bench.server.stats.get("lease_expired", 0) == 0
        finally:
            body.close()


def test_lease_expires_without_refresh_and_stops_the_body(port, raw):
    k = Keys(RID)
    # a 0.5 s lease: the Move (after two more queries) must come within it also on a loaded machine
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], body=FAST, lease_ttl_s=0.5, estop_timeout_s=5.0) as bench:
        s = raw()
        ask(s, k.estop_checkin, encode("checkin", {"client": "x", "seq": 1}))
        ok, rep = ask(s, k.lease_acquire, encode("lease_acquire", {"client": "x"}))
        assert ok
        ok, _ = ask(s, k.cmd_move, encode("move", {"client": "x", "lease": rep["lease"], "goal": pose_map(5, 0, 0),
                                                    "timeout_ns": 10**10}))
        assert ok and wait_for(lambda: bench.sim.moving, 1.0)
        assert wait_for(lambda: bench.server.stats.get("lease_expired") == 1, 2.0)
        assert not bench.sim.moving and bench.server.lease_holder is None
        ok, _ = ask(s, k.lease_acquire, encode("lease_acquire", {"client": "y"}))
        assert ok


def test_estop_keepalive_timeout_stops_the_body(port, raw):
    k = Keys(RID)
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], body=FAST, estop_timeout_s=0.3) as bench:
        s = raw()
        t_sent = time.monotonic()
        ok, rep = ask(s, k.estop_checkin, encode("checkin", {"client": "x", "seq": 1}))
        t_acked = time.monotonic()
        assert ok and rep["timeout_ns"] == 300_000_000
        assert wait_for(lambda: not bench.sim.estop, 1.0)
        _, lease = ask(s, k.lease_acquire, encode("lease_acquire", {"client": "x"}))
        ok, _ = ask(s, k.cmd_move, encode("move", {"client": "x", "lease": lease["lease"], "goal": pose_map(5, 0, 0),
                                                    "timeout_ns": 10**10}))
        assert ok and wait_for(lambda: bench.sim.moving, 1.0)
        # no more check-ins: stopped 0.3 s after the last one, which the robot side stamped between
        # t_sent and t_acked (timed from after the lease and move queries, a loaded machine's
        # slower queries made a correct stop look early)
        assert wait_for(lambda: not bench.sim.moving, 1.0)
        t_stop = time.monotonic()
        assert t_stop - t_sent >= 0.3 and t_stop - t_acked < 0.6, (t_stop - t_sent, t_stop - t_acked)
        assert bench.sim.estop and bench.sim.estop_reason == "estop_keepalive_timeout"
        assert bench.server.stats["estop_timeouts"] == 1
        # refused while engaged; the next check-in releases it
        ok, rep = ask(s, k.cmd_move, encode("move", {"client": "x", "lease": lease["lease"],
                                                     "goal": pose_map(0, 0, 0), "timeout_ns": 10**9}))
        assert not ok and rep["error"] == "estop"
        ask(s, k.estop_checkin, encode("checkin", {"client": "x", "seq": 2}))
        assert not bench.sim.estop


def _checkin(s, client: str, seq: int, **kw) -> tuple[bool, dict]:
    return ask(s, Keys(RID).estop_checkin, encode("checkin", {"client": client, "seq": seq, **kw}))


def _lease(s, client: str, token: str | None = None) -> tuple[bool, dict]:
    return ask(s, Keys(RID).lease_acquire, encode("lease_acquire", {"client": client, "lease": token}))


def _move(s, client: str, token: str, x: float) -> tuple[bool, dict]:
    return ask(s, Keys(RID).cmd_move, encode("move", {"client": client, "lease": token, "goal": pose_map(x, 0, 0),
                                                      "timeout_ns": 10**10}))


def test_lease_refresh_needs_the_token_not_only_the_client_id(port, raw):
    """The holder's id is public (State.lease_holder): another session naming it, without the
    token or with a wrong one, gets neither the token nor the body."""
    k = Keys(RID)
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], body=FAST, estop_timeout_s=5.0) as bench:
        a, b = raw(), raw()
        _checkin(a, "alpha", 1)
        ok, rep = _lease(a, "alpha")
        assert ok
        token = rep["lease"]
        for t in (None, "0" * 16):
            ok, err = _lease(b, "alpha", t)
            assert not ok and err["error"] == "lease_refused" and token not in err["detail"], err
        ok, err = ask(b, k.lease_release, encode("lease_release", {"client": "alpha", "lease": "0" * 16}))
        assert not ok and err["error"] == "no_lease" and "token does not match" in err["detail"]
        assert bench.server.lease_holder == "alpha"
        ok, rep = _lease(a, "alpha", token)  # the holder's refresh: same token
        assert ok and rep["lease"] == token
        assert bench.server.stats["lease_without_token"] == 1  # the raw sessions declared no P/client token


def test_only_the_lease_holders_checkins_keep_its_body_moving(port, raw):
    """Commander A walks and goes silent while B keeps checking in: A's body stops on the keep-alive."""
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], body=FAST, estop_timeout_s=0.3, lease_ttl_s=30.0) as bench:
        a, b = raw(), raw()
        _checkin(a, "alpha", 1)
        _, rep = _lease(a, "alpha")
        ok, _ = _move(a, "alpha", rep["lease"], 5.0)
        assert ok and wait_for(lambda: bench.sim.moving, 1.0)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 1.0 and bench.sim.moving:
            _checkin(b, "bravo", int(1000 * (time.monotonic() - t0)) + 1)
            time.sleep(0.05)
        assert not bench.sim.moving and bench.sim.estop_reason == "estop_keepalive_timeout"
        assert time.monotonic() - t0 < 0.8


def test_engaged_estop_holds_until_its_engager_releases_it(port, raw):
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], body=FAST, estop_timeout_s=5.0) as bench:
        a, b = raw(), raw()
        token = a.liveliness().declare_token(Keys(RID).client("alpha"))  # alpha's session is open
        # (liveliness arrives asynchronously: under load the server could still miss alpha's token
        # when bravo asks to release, and rightly let it)
        assert wait_for(lambda: "alpha" in bench.server._live_clients, 2.0)
        _checkin(a, "alpha", 1)
        assert wait_for(lambda: not bench.sim.estop, 1.0)
        ok, rep = _checkin(a, "alpha", 2, engage=True)
        assert ok and rep["estop"] and bench.sim.estop_reason == "estop_engaged_by_client"
        for c, seq in (("alpha", 3), ("bravo", 1)):  # plain check-ins (the keep-alive) keep it
            ok, rep = _checkin(a if c == "alpha" else b, c, seq)
            assert ok and rep["estop"], c
        ok, err = _checkin(b, "bravo", 2, engage=False)  # not bravo's to release while alpha lives
        assert not ok and err["error"] == "estop" and bench.sim.estop
        ok, rep = _checkin(a, "alpha", 4, engage=False)
        assert ok and not rep["estop"] and not bench.sim.estop
        ok, rep = _checkin(a, "alpha", 5, engage=True)
        token.undeclare()  # alpha's session ends: its engage no longer binds anybody ...
        assert wait_for(lambda: _checkin(b, "bravo", 4, engage=False)[0], 2.0)  # ... an explicit release works
        assert not bench.sim.estop


def test_client_engage_survives_its_own_keepalive_until_released(port):
    from drivers.interfaces import EStopActive

    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], body=FAST) as bench:
        a = ZenohBody(ZenohBodyConfig.loopback(port, RID, client_id="alice"))
        try:
            a.engage_estop()
            n = a.stats["checkins"]
            assert wait_for(lambda: a.stats["checkins"] >= n + 2, 2.0)  # the background keep-alive ran
            with pytest.raises(EStopActive):
                a.move_to(SE2(0.2, 0.0, 0.0), timeout=5.0)
            assert bench.sim.moves == 0
            assert a.release_estop()
            assert a.move_to(SE2(0.2, 0.0, 0.0), timeout=5.0).ok
        finally:
            a.close()


def test_a_preempted_or_stopped_move_reports_its_end_once(port, raw):
    k = Keys(RID)
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], body=FAST, estop_timeout_s=5.0) as bench:
        s = raw()
        fb: list[dict] = []
        sub = s.declare_subscriber(k.feedback, lambda smp: fb.append(decode("feedback", smp.payload.to_bytes())))
        _checkin(s, "alpha", 1)
        _, rep = _lease(s, "alpha")
        tok = rep["lease"]
        _, m1 = _move(s, "alpha", tok, 5.0)
        assert wait_for(lambda: bench.sim.moving, 1.0)
        _, m2 = _move(s, "alpha", tok, -5.0)  # preempts m1
        ask(s, k.cmd_stop, encode("stop", {"client": "alpha"}))
        _, m3 = _move(s, "alpha", tok, 0.0)  # right after the stop, maybe within one loop tick
        assert wait_for(lambda: len(fb) >= 2, 2.0)
        ask(s, k.cmd_stop, encode("stop", {"client": "alpha"}))
        assert wait_for(lambda: len(fb) >= 3, 2.0)
        time.sleep(0.1)
        ends = [(f["cmd_id"], f["status"], f["reason"]) for f in fb]
        assert ends[:2] == [(m1["cmd_id"], "stopped", "preempted"), (m2["cmd_id"], "stopped", "stop_requested")], ends
        assert len(ends) == 3 and ends[2][0] == m3["cmd_id"] and ends[2][1] in ("succeeded", "stopped"), ends
        sub.undeclare()


def test_commander_session_gone_stops_the_body(port):
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], body=FAST, estop_timeout_s=5.0) as bench:
        a = ZenohBody(ZenohBodyConfig.loopback(port, RID, client_id="alice"))
        t = threading.Thread(target=lambda: pytest.raises(Exception, a.move_to, SE2(5, 0, 0), 10.0), daemon=True)
        t.start()
        assert wait_for(lambda: bench.sim.moving, 2.0)
        a._session.close()  # the session dies without releasing anything (a crashed executive)
        assert wait_for(lambda: not bench.sim.moving, 1.0)
        assert bench.server.stats["commander_lost"] == 1
        a.close()
        t.join(2.0)


def _move_in_thread(body: ZenohBody, goal: SE2, timeout: float) -> dict:
    out: dict = {}

    def run() -> None:
        try:
            out["result"] = body.move_to(goal, timeout)
        except Exception as e:  # noqa: BLE001 - the test inspects it
            out["error"], out["t"] = e, time.monotonic()

    out["thread"] = threading.Thread(target=run, daemon=True)
    out["thread"].start()
    return out


def test_no_move_follows_close(port):
    """A move_to of another thread while close() runs is refused (LinkLost) and never reaches the
    robot side. Made certain here: the move starts right after close() has released the lease.
    Before the fix it acquired a new lease and the body walked off after close()."""
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], body=FAST, estop_timeout_s=5.0) as bench:
        a = ZenohBody(ZenohBodyConfig.loopback(port, RID, client_id="alice"))
        assert a.move_to(SE2(0.1, 0.0, 0.0), timeout=5.0).ok  # holds the lease
        moves = bench.sim.moves
        late: dict = {}
        real_release = a.release_lease

        def release(timeout: float = 0.5) -> None:
            real_release(timeout)
            late.update(_move_in_thread(a, SE2(3.0, 0.0, 0.0), 5.0))
            late["thread"].join(2.0)

        a.release_lease = release
        a.close()
        late["thread"].join(2.0)
        assert bench.sim.moves == moves and not bench.sim.moving, "a move reached the robot side after close()"
        assert isinstance(late.get("error"), LinkLost), late


def test_robot_side_killed_is_link_lost_within_50ms():
    slow: list[float] = []
    for _ in range(3):  # 50 ms is a quiet machine's figure: only three late detections in a row fail
        detect_ms = _kill_robot_side_and_detect(free_port())
        if detect_ms <= 50.0:
            break
        slow.append(round(detect_ms, 1))
    assert detect_ms <= 50.0, f"link loss reported after {slow} ms"


def _kill_robot_side_and_detect(port: int) -> float:
    proc = spawn_server(port, RID)
    try:
        body = ZenohBody(ZenohBodyConfig.loopback(port, RID))
        try:
            mv = _move_in_thread(body, SE2(5.0, 0.0, 0.0), 30.0)
            assert wait_for(lambda: body.state().moving, 2.0)
            t_kill = time.monotonic()
            os.kill(proc.pid, signal.SIGKILL)
            mv["thread"].join(2.0)
            assert isinstance(mv.get("error"), LinkLost), mv
            assert "liveliness" in str(mv["error"])
            assert body.state().fault.startswith("link_lost")
            with pytest.raises(LinkLost):
                body.move_to(SE2(0, 0, 0), 1.0)
            assert proc.wait(2.0) == -signal.SIGKILL  # the robot side (and its body) is gone
            return (mv["t"] - t_kill) * 1e3
        finally:
            body.close()
    finally:
        proc.kill()
        proc.wait()


def test_robot_side_frozen_is_link_lost_within_the_lease_and_stops_on_resume(port, raw):
    lease_ms = 1000
    proc = spawn_server(port, RID, "--lease-ms", str(lease_ms), "--estop-timeout", "0.4")
    try:
        body = ZenohBody(ZenohBodyConfig.loopback(port, RID, lease_ms=lease_ms))
        try:
            mv = _move_in_thread(body, SE2(5.0, 0.0, 0.0), 30.0)
            assert wait_for(lambda: body.state().moving, 2.0)
            t_stop = time.monotonic()
            os.kill(proc.pid, signal.SIGSTOP)
            mv["thread"].join(3.0)
            assert isinstance(mv.get("error"), LinkLost), mv
            detect_ms = (mv["t"] - t_stop) * 1e3
            assert detect_ms <= lease_ms, f"frozen robot side reported after {detect_ms:.0f} ms"
            assert "stalled" in str(mv["error"])
        finally:
            os.kill(proc.pid, signal.SIGCONT)
        # Resumed robot side: no check-ins came while it was frozen, so it stops on its own.
        s = raw()
        states: list[dict] = []
        sub = s.declare_subscriber(Keys(RID).state, lambda smp: states.append(decode("state", smp.payload.to_bytes())))
        # (a stop or check-in queued before the freeze may still land first; the keep-alive
        # timeout follows because the latched client checks in no more)
        assert wait_for(lambda: len(states) > 5 and not states[-1]["moving"] and states[-1]["estop"], 5.0)
        assert states[-1]["estop_reason"] == "estop_keepalive_timeout"
        x = states[-1]["pose"]["x"]
        time.sleep(0.2)
        assert states[-1]["pose"]["x"] == x and not states[-1]["moving"]
        sub.undeclare()
        body.close()
    finally:
        proc.kill()
        proc.wait()


def test_clean_shutdown_no_hang_at_exit(port):
    proc = spawn_server(port, RID)
    try:
        # A client that forgets close(): the interpreter must still exit promptly.
        script = (
            "from drivers.zenoh_body import ZenohBody, ZenohBodyConfig\n"
            "from capm_field.geometry import SE2\n"
            f"b = ZenohBody(ZenohBodyConfig.loopback({port}, {RID!r}))\n"
            "assert b.move_to(SE2(0.1, 0.0, 0.0), 10.0).ok\n"
            "print('moved')\n"
        )
        out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=30)
        assert out.returncode == 0 and "moved" in out.stdout, out.stderr[-1000:]
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(5.0) == 0
    finally:
        proc.kill()
        proc.wait()


def test_no_robot_side_is_a_clear_link_lost(port):
    with pytest.raises(LinkLost, match="no robot side"):
        ZenohBody(ZenohBodyConfig.loopback(port, RID, connect_timeout_s=0.3))


def test_frozen_sim_hook_is_link_lost_by_state_stall(port):
    # The in-process freeze hook (no answers, no state, TCP open) as the fault-injection layer will use it.
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], body=FAST) as bench:
        body = ZenohBody(ZenohBodyConfig.loopback(port, RID, state_stale_s=0.2))
        try:
            mv = _move_in_thread(body, SE2(5.0, 0.0, 0.0), 30.0)
            assert wait_for(lambda: body.state().moving, 2.0)
            t0 = time.monotonic()
            bench.sim.freeze()
            mv["thread"].join(2.0)
            assert isinstance(mv.get("error"), LinkLost) and "stalled" in str(mv["error"])
            assert mv["t"] - t0 < 0.6  # 0.2 s stale + scheduling on a loaded machine (the move's own timeout is 30 s)
        finally:
            body.close()
            bench.sim.freeze(False)


def test_the_state_at_start_shows_the_checkin_that_released_the_estop(port):
    """The robot side's loop reads its state, then publishes it: a State published just after our
    CheckIn's reply may have been read before the CheckIn released the E-stop. Here every publish
    comes 30 ms after its read (a descheduled loop on a loaded machine): the client's state at start
    must still show the release, or the mission refuses to start ("E-stop engaged")."""
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"], body=FAST) as bench:
        pub = bench.server._state_pub

        class LatePublisher:
            def put(self, payload, *a, **k):
                time.sleep(0.03)
                return pub.put(payload, *a, **k)

            def __getattr__(self, name):
                return getattr(pub, name)

        bench.server._state_pub = LatePublisher()
        for _ in range(3):
            body = ZenohBody(ZenohBodyConfig.loopback(port, RID))
            try:
                assert not body.state().estop, body.state()
            finally:
                body.close()
