"""A stall of this process is not a silent peer (drivers/host_stall.py; a timing audit: a 0.4 s
host stall mid-flame ended the mission as "no heartbeat from HB_IGN_BOARD", a 0.6 s one E-stopped a
healthy robot as "state stream stalled").

The stall is made by holding the GIL in a pure-Python loop with a switch interval longer than the
loop: no other Python thread of this process runs meanwhile (the link watchdogs, the CAN Notifier,
zenoh's callbacks), as when the process is descheduled or paged out."""

from __future__ import annotations

import sys
import time

from drivers.host_stall import HostClock, host_clock
from drivers.zenoh_body import ZenohBody, ZenohBodyConfig
from sim_bench.can_rig import CanBench
from sim_bench.zenoh_body_server import free_port, spawn_server
from waiting import wait_for


def _stall(seconds: float) -> None:
    """Hold the GIL for `seconds` (no other thread of this process runs)."""
    old = sys.getswitchinterval()
    sys.setswitchinterval(seconds + 1.0)
    try:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            pass
    finally:
        sys.setswitchinterval(old)


def test_the_clock_tells_a_stall_from_a_quiet_peer():
    clock = HostClock()
    time.sleep(0.05)
    heard = time.monotonic_ns() - 10**9  # a peer last heard 1 s ago, the host running all along
    assert clock.silent_since(heard) == heard
    _stall(0.3)
    now = time.monotonic_ns()
    assert clock.silent_since(heard) >= now  # woke before the ticker: counts from now
    time.sleep(0.05)
    assert clock.stalls >= 1 and clock.silent_since(heard) >= now - 30_000_000  # from the end of the stall
    long_ago = time.monotonic_ns() - 5 * 10**9  # stalls postpone a silence by 2 s at most
    assert clock.silent_since(long_ago) == long_ago + 2 * 10**9


def test_a_host_stall_longer_than_the_heartbeat_timeout_does_not_lose_the_can_link():
    bench = CanBench(with_arm=False, heartbeat_timeout=0.3)
    try:
        ign = bench.igniter
        host_clock()  # (started with the link; running before the stall)
        wait_for(lambda: ign.link.ok, 2.0)
        _stall(0.45)  # the board's heartbeats (same process here) stop too: none is queued
        time.sleep(0.35)
        assert ign.link.ok, ign.link.lost_reason
        bench.robot_side.close()  # a peer that really goes quiet is still found lost
        assert wait_for(lambda: not ign.link.ok, 2.0)
        assert "no heartbeat" in ign.link.lost_reason
    finally:
        bench.close()


class _JustResumed:
    """A host clock whose process has just come out of a stall (its ticker not yet run)."""

    def silent_since(self, last_heard_ns: int) -> int:
        return time.monotonic_ns()


def test_the_can_watchdog_counts_the_peers_silence_from_the_end_of_a_host_stall():
    """The watchdog woken first after a stall, the peer's queued heartbeats not yet drained by the
    Notifier: its last heartbeat looks 0.5 s old, but the host, not the peer, was silent."""
    bench = CanBench(with_arm=False, heartbeat_timeout=0.3)
    try:
        link = bench.igniter.link
        wait_for(lambda: link.ok, 2.0)
        link._host = _JustResumed()
        with link._lock:
            link.last_peer_hb_ns = time.monotonic_ns() - 500_000_000
        link._wake.set()
        time.sleep(0.05)
        assert link.ok, link.lost_reason
    finally:
        bench.close()


def test_a_host_stall_longer_than_the_state_stall_limit_does_not_latch_the_body_link_lost():
    port = free_port()
    proc = spawn_server(port, "stall")  # the robot side in its own process: it goes on publishing
    body = ZenohBody(ZenohBodyConfig.loopback(port, "stall"))
    try:
        wait_for(lambda: body.state().fault is None, 5.0)
        _stall(0.75)  # over the 0.5 s stall limit (lease 1 s / 2)
        st = body.state()  # before any callback has delivered the queued states
        assert not (st.fault or "").startswith("link_lost"), st.fault
        assert wait_for(lambda: body.state().fault is None, 2.0), body.state().fault
    finally:
        body.close()
        proc.terminate()
        proc.wait(10)


def test_a_host_stall_mid_flame_ends_the_trial_as_the_boards_trip_not_a_lost_link():
    """A 0.35 s stall of the host mid-hold (over the 0.25 s status limit): the board trips on the
    missing keep-alives (valve shut by its own timer) and says so once the host runs again; the trial
    ends `keepalive_timeout`, which the executive re-arms once for (docs/faults.md), not LinkLost
    or a blind `status_stale` that skipped the target."""
    bench = CanBench(with_arm=False, heartbeat_timeout=0.3)
    try:
        ign, board = bench.igniter, bench.robot_side.board
        wait_for(lambda: ign.link.ok, 2.0)
        ign.arm(timeout=1.0)
        t0 = time.monotonic()
        stalled = []

        def permit() -> bool:
            if not stalled and time.monotonic() - t0 > 0.5:
                stalled.append(1)
                _stall(0.35)
            return True

        r = ign.ignite(3.0, permit, timeout=5.0)
        assert stalled and not r.ok and r.reason == "keepalive_timeout", r
        assert ign.link.ok, ign.link.lost_reason
        time.sleep(0.1)
        assert not board.flame_on and not board.valve_open
        ign.arm(timeout=1.0)  # one more trial, as the executive does
        assert ign.ignite(0.3, lambda: True, timeout=2.0).ok
    finally:
        bench.close()
