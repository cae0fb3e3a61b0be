"""Board and gateway contract details of docs/protocols/can.md that a third-party client relies
on: the igniter trips (valve shut AND disarmed) on a keep-alive gap or a rejected command while
the valve is open, and resumed keep-alives never re-light it; ARM_TARGET/ARM_STATE halves pair
only when B directly follows its A within 30 ms (PAIR_WINDOW_S); both nodes count unknown and 29-bit ids alike;
targets while DISABLED are ignored and not counted; RESET_FAULT works without the host
heartbeat, ENABLE does not; a non-operational host heartbeat is a lost host.

Board logic on a simulated clock (deterministic); wire tests on python-can `virtual` with a bare
host (`RawHost`), waiting on conditions with generous deadlines (2 loaded cores)."""

from __future__ import annotations

import math
import threading
import time

import can
import numpy as np
import pytest

from drivers.can.codec import (
    ARM_DISABLE,
    ARM_ENABLE,
    ARM_NOP,
    ARM_RESET,
    IGN_ARM,
    IGN_DISARM,
    IGN_EVENT_CODES,
    IGN_EXTINGUISH,
    IGN_IGNITE,
    NMT_PRE_OPERATIONAL,
    NODE_HOST_IGN,
    SetPairer,
)
from sim_bench.can_rig import CanBench, RawHost
from sim_bench.sim_arm import DISABLED, FAULT, HOLDING
from sim_bench.sim_igniter import IgniterBoard
from waiting import wait_for

KA = IGN_EVENT_CODES["keepalive_timeout"]
BAD = IGN_EVENT_CODES["bad_frame"]
HOST_LOST = IGN_EVENT_CODES["host_lost"]
NOT_ARMED = IGN_EVENT_CODES["not_armed"]


# ---- board logic, simulated clock ----------------------------------------------------------
def _burning_board(t_lit: float = 0.3) -> tuple[IgniterBoard, float]:
    """A board lit by IGNITE every 20 ms on 1 ms ticks; returns it and the last keep-alive time."""
    b = IgniterBoard()
    b.arm(0.0)
    t, last = 0.0, 0.0
    while t < t_lit:
        if round(t * 1000) % 20 == 0:
            b.ignite(t)
            last = t
        b.tick(t)
        t = round(t + 0.001, 6)
    assert b.flame_on
    return b, last


def test_board_logic_off_within_100ms_of_last_keepalive():
    """The board's rule on a simulated clock (1 ms ticks, like the firmware timer): deterministic."""
    for gap_at in (0.2, 0.2137, 0.5):
        b, last = _burning_board(gap_at)
        t = round(math.ceil(gap_at * 1000 - 1e-6) / 1000, 6)  # the first tick the helper did not run
        while b.valve_open:
            b.tick(t)
            t = round(t + 0.001, 6)
        assert b.event == "keepalive_timeout"
        assert 0.08 < b.flame_off_at - last <= 0.1


def _run_gap(b: IgniterBoard, last: float, gap: float) -> None:
    t = last
    while t < last + gap:
        t = round(t + 0.001, 6)
        b.tick(t)
    b.ignite(round(last + gap, 6))


def test_board_keepalive_gap_trips_and_disarms():
    b, last = _burning_board()
    _run_gap(b, last, 0.15)
    assert not b.valve_open and not b.flame_on and not b.armed
    assert b.event == "not_armed"  # the resumed IGNITE was refused...
    assert 0.08 < b.flame_off_at - last <= 0.1
    for k in range(1, 30):  # ...and so is every later one: no new trial without ARM
        b.ignite(last + 0.15 + 0.02 * k)
        b.tick(last + 0.15 + 0.02 * k)
        assert not b.valve_open
    b.arm(1.0)
    assert b.armed and b.event is None  # an accepted ARM clears the sticky Event
    b.ignite(1.0)
    assert b.valve_open and b.igniting


def test_board_timer_runs_on_its_own_through_a_host_stall():
    """Ticked only after a 0.15 s stall (the simulated host was descheduled): the valve shut, and
    the fuel stopped burning, when the board's own timer saw the gap, not when the host resumed."""
    b, last = _burning_board()
    fuel = b.fuel
    b.tick(last + 0.15)
    assert not b.valve_open and not b.armed and b.event == "keepalive_timeout"
    assert 0.08 < b.flame_off_at - last <= 0.1
    burnt_s = (fuel - b.fuel) / b.p.fuel_per_s  # since the helper's last tick at last + 0.019
    assert 0.06 < burnt_s <= 0.082, burnt_s


def test_board_late_keepalive_after_expired_gap_trips_even_without_a_tick():
    b, last = _burning_board()
    b.ignite(last + 0.09)  # arrives after the 80 ms gap expired, before the board's timer saw it
    assert not b.valve_open and not b.armed and b.event == "keepalive_timeout"
    assert 0.08 < b.flame_off_at - last <= 0.082  # shut by the board's timer, before that frame


def test_board_gap_during_trial_trips_too():
    b = IgniterBoard()
    b.arm(0.0)
    b.ignite(0.0)
    b.tick(0.05)
    assert b.igniting
    b.tick(0.081)
    assert not b.valve_open and not b.armed and b.event == "keepalive_timeout"


@pytest.mark.parametrize("gap", [0.02, 0.04, 0.06, 0.079])
def test_board_two_lost_keepalives_do_not_drop_the_flame(gap):
    b, last = _burning_board()
    _run_gap(b, last, gap)
    assert b.flame_on and b.armed


def test_board_rejected_command_while_open_trips_but_not_while_idle():
    b, last = _burning_board()
    b.frame_rejected(last + 0.005, command=True)
    assert not b.valve_open and not b.armed and b.event == "bad_frame" and b.rejected == 1
    b = IgniterBoard()
    b.arm(0.0)
    b.frame_rejected(0.01, command=True)  # idle: counted, never acted on, stays armed
    b.frame_rejected(0.01, command=False)  # another id (unknown, 29-bit): counted only
    assert b.armed and b.event is None and b.rejected == 2


def test_board_host_lost_while_armed_reports_host_lost():
    b = IgniterBoard()
    b.arm(0.0)
    b.host_lost(0.1)
    assert not b.armed and b.event == "host_lost"


# ---- wire: igniter board ---------------------------------------------------------------------
def _wait(pred, timeout: float = 2.0) -> bool:
    return wait_for(pred, timeout, step=0.005)


def _keepalives(host: RawHost, duration: float) -> None:
    end = time.monotonic() + duration
    nxt = time.monotonic()
    while time.monotonic() < end:
        host.ign(IGN_IGNITE)
        nxt += 0.02
        time.sleep(max(0.0, nxt - time.monotonic()))


def test_keepalive_gap_disarms_and_ignite_alone_does_not_relight(raw):
    bench, host = raw
    host.light()
    host.ign(IGN_IGNITE)
    time.sleep(0.15)  # the gap under test (a longer one on a loaded machine tests the same rule)
    assert host.wait_ign(lambda s: s["Armed"] == 0 and s["FlameOn"] == 0 and s["Igniting"] == 0, 1.0)
    assert host.ign_status["Event"] == KA
    t_resume = time.monotonic()
    _keepalives(host, 0.5)  # a host resuming its keep-alives (> light delay + a trial's worth)
    assert host.wait_ign(lambda s: s["Event"] == NOT_ARMED, 1.0)
    seen = host.statuses_since(t_resume)
    assert seen and not any(s["FlameOn"] or s["Igniting"] or s["Armed"] for s in seen)
    b = bench.robot_side.board
    with bench.robot_side.lock:
        assert not b.valve_open and not b.armed
    host.light()  # an explicit ARM makes it usable again


def test_a_stale_burst_of_the_hosts_own_frames_does_not_rearm_a_tripped_board(raw):
    """After a keep-alive trip, the host's earlier DISARM, ARM, IGNITE ×4 arrive again with their
    old counters, back to back (a stuck mailbox flushed): the first is rejected by the counter
    and the rest follow it in step, but within the resync hold (can.md rule 7) a node acts on no
    ARM or IGNITE: the board stays disarmed, the valve shut, and all six are counted."""
    bench, host = raw
    host.light()
    time.sleep(0.15)  # no keep-alive: the board trips and disarms
    assert host.wait_ign(lambda s: s["Armed"] == 0 and s["FlameOn"] == 0, 1.0)
    c_next = host.enc.next_counter("IGN_CMD")  # the host's counter has moved on
    rej0 = host.ign_status["RxRejected"]
    t0 = time.monotonic()
    c0 = (c_next - 8) & 0x0F  # behind the board's last accepted counter: stale
    for k, cmd in enumerate((IGN_DISARM, IGN_ARM, IGN_IGNITE, IGN_IGNITE, IGN_IGNITE, IGN_IGNITE)):
        host.ign(cmd, counter=(c0 + k) & 0x0F)
    assert host.wait_ign(lambda s: s["RxRejected"] == (rej0 + 6) & 0xFF, 1.0), host.ign_status
    time.sleep(0.1)
    seen = host.statuses_since(t0)
    assert seen and not any(s["Armed"] or s["FlameOn"] or s["Igniting"] for s in seen)
    rs = bench.robot_side
    with rs.lock:
        assert not rs.board.valve_open and not rs.board.armed
    assert rs.ign_rx.stats.rejected["resync_hold"] == 5


def test_a_descheduled_board_takes_frames_at_their_bus_time(raw):
    """The simulated board's thread held up 150 ms (a busy test machine) while the host's
    keep-alives went out every 20 ms: the board acts on each frame at its bus time and drains
    them before its timer runs, so it does not trip — a real board's receiver is an interrupt.
    Retried only if the host's own sends left a gap longer than the board's timeout."""
    bench, host = raw
    rs = bench.robot_side
    for _ in range(3):
        host.light()
        sent: list[float] = []

        def keepalives() -> None:
            end = time.monotonic() + 0.45
            while time.monotonic() < end:
                sent.append(host.ign(IGN_IGNITE))
                time.sleep(max(0.0, sent[-1] + 0.02 - time.monotonic()))

        th = threading.Thread(target=keepalives)
        th.start()
        time.sleep(0.1)
        with rs.lock:
            time.sleep(0.15)
        th.join()
        with rs.lock:
            lit = rs.board.flame_on
        if lit or max(np.diff(sent)) <= rs.board.p.keepalive_timeout:
            break
    assert lit, (rs.board.event, max(np.diff(sent)))
    host.ign(IGN_EXTINGUISH)
    assert host.wait_ign(lambda s: s["FlameOn"] == 0, 1.0)


def test_rejected_ign_cmd_while_burning_disarms(raw):
    _, host = raw
    for _ in range(5):  # a retry only if this thread stalled > 80 ms and the gap tripped it first
        host.light()
        rej0 = host.ign_status["RxRejected"]
        good = host.enc.encode("IGN_CMD", {"Command": IGN_IGNITE})
        bad = bytearray(good.data)
        bad[7] ^= 0xFF
        host.ign(IGN_IGNITE)
        t_bad = host.send(can.Message(arbitration_id=0x120, data=bytes(bad), is_extended_id=False))
        t_off = host.wait_ign(lambda s: s["FlameOn"] == 0 and s["Armed"] == 0, 1.0)
        assert t_off is not None
        if host.ign_status["Event"] != KA:
            break
    assert host.ign_status["Event"] == BAD
    assert host.ign_status["RxRejected"] == (rej0 + 1) & 0xFF
    t_resume = time.monotonic()
    _keepalives(host, 0.3)
    assert not any(s["FlameOn"] or s["Igniting"] for s in host.statuses_since(t_resume))
    assert t_off - t_bad < 0.5  # sanity; the rule itself: shut on the frame (logic test above)


def test_unknown_and_extended_ids_are_counted_alike_by_both_nodes(raw):
    bench, host = raw
    rs = bench.robot_side
    host.ign(IGN_ARM)
    assert host.wait_ign(lambda s: s["Armed"] == 1, 1.0)
    with rs.lock:
        gw0, bd0 = rs.arm_rx.stats.rejected_total, rs.board.rejected
        mode0 = rs.arm.mode
    disable = host.enc.encode("ARM_CMD", {"Command": ARM_DISABLE})
    host.send(can.Message(arbitration_id=0x555, data=bytes(8), is_extended_id=False))  # unknown 11-bit id
    host.send(can.Message(arbitration_id=0x121, data=disable.data, is_extended_id=True))  # 29-bit "ARM_CMD"
    ign = host.enc.encode("IGN_CMD", {"Command": 2})  # DISARM, as a 29-bit frame
    host.send(can.Message(arbitration_id=0x120, data=ign.data, is_extended_id=True))
    assert _wait(lambda: rs.arm_rx.stats.rejected_total == gw0 + 3 and rs.board.rejected == bd0 + 3)
    assert host.wait_ign(lambda s: s["RxRejected"] == (bd0 + 3) & 0xFF, 1.0)
    with rs.lock:
        assert rs.arm_rx.stats.rejected["unknown_id"] >= 1 and rs.arm_rx.stats.rejected["extended_id"] == 2
        assert rs.ign_rx.stats.rejected["unknown_id"] >= 1 and rs.ign_rx.stats.rejected["extended_id"] == 2
        assert rs.board.armed and rs.arm.mode == mode0  # never acted on


def test_non_operational_host_heartbeat_is_host_lost(raw):
    _, host = raw
    host.ign(IGN_ARM)
    assert host.wait_ign(lambda s: s["Armed"] == 1, 1.0)
    host.stop_heartbeat()
    host.send(host.enc.heartbeat("HB_HOST_IGN", NODE_HOST_IGN, 0.1, state=NMT_PRE_OPERATIONAL))
    assert host.wait_ign(lambda s: s["Armed"] == 0 and s["Event"] == HOST_LOST, 1.0)


# ---- wire: arm gateway -------------------------------------------------------------------------
@pytest.fixture
def gw(raw):
    bench, host = raw
    rs = bench.robot_side
    host.arm_cmd(ARM_ENABLE)
    assert _wait(lambda: rs.arm.mode == HOLDING)
    yield rs, host


def _snapshot(rs):
    with rs.lock:
        return rs.arm.targets_applied, rs.arm_rx.stats.rejected["pair"], rs.arm_rx.stats.rejected_total, rs.arm.q.copy()


def _prompt_pair(rs, host, q, tries: int = 20) -> bool:
    """A then B right away; True once the gateway applied one (a send gap > 8 ms from a descheduled
    test thread is not a prompt pair: try again)."""
    for _ in range(tries):
        n0 = _snapshot(rs)[0]
        c = host.next_target_counter()
        ta = host.target_half("A", q[:3], c)
        tb = host.target_half("B", q[3:], c)
        if tb - ta > 0.008:
            continue
        if _wait(lambda n0=n0: rs.arm.targets_applied > n0, 1.0):
            return True
    return False


def test_prompt_target_pair_is_applied(gw):
    rs, host = gw
    q = _snapshot(rs)[3] + np.array([0.01, 0, 0, 0, 0, 0])
    assert _prompt_pair(rs, host, q)
    assert _wait(lambda: rs.arm.mode in ("tracking", HOLDING))


def test_late_b_half_is_discarded_and_counted(gw):
    rs, host = gw
    n0, pair0, _, q0 = _snapshot(rs)
    q = q0 + np.array([0.02, 0, 0, 0, 0, 0])
    c = host.next_target_counter()
    host.target_half("A", q[:3], c)
    time.sleep(0.15)  # B held back (the foreign client's finding: it used to be applied)
    host.target_half("B", q[3:], c)
    assert _wait(lambda: rs.arm_rx.stats.rejected["pair"] == pair0 + 1)
    n, _, _, q1 = _snapshot(rs)
    assert n == n0 and np.allclose(q1, q0, atol=1e-6) and rs.arm.mode == HOLDING


@pytest.mark.parametrize("between", ["other_a", "rejected_b", "command"])
def test_b_half_must_directly_follow_its_a(gw, between):
    rs, host = gw
    n0, pair0, _, q0 = _snapshot(rs)
    q = q0 + np.array([0.01, 0, 0, 0, 0, 0])
    c = host.next_target_counter()
    host.target_half("A", q[:3], c)
    if between == "other_a":
        host.target_half("A", q[:3], host.enc.next_counter("ARM_TARGET_A"))
    elif between == "rejected_b":
        m = host.enc.encode("ARM_TARGET_B", {"J4_Target": 0.0, "J5_Target": 0.0, "J6_Target": 0.0}, counter=c)
        data = bytearray(m.data)
        data[7] ^= 0xFF
        host.send(can.Message(arbitration_id=m.arbitration_id, data=bytes(data), is_extended_id=False))
    else:
        host.arm_cmd(ARM_NOP)
    host.target_half("B", q[3:], c)
    assert _wait(lambda: rs.arm_rx.stats.rejected["pair"] == pair0 + 1)
    assert _snapshot(rs)[0] == n0
    assert _prompt_pair(rs, host, q)  # the stream carries on with the next complete pair


def test_targets_while_disabled_are_ignored_and_not_counted(gw):
    rs, host = gw
    host.arm_cmd(ARM_DISABLE)
    assert _wait(lambda: rs.arm.mode == DISABLED)
    n0, pair0, rej0, q0 = _snapshot(rs)
    q = q0 + np.array([0.01, 0, 0, 0, 0, 0])
    for _ in range(5):
        c = host.next_target_counter()
        host.target_half("A", q[:3], c)
        host.target_half("B", q[3:], c)
    time.sleep(0.1)  # nothing should happen: give the gateway time to (not) act
    n, pair, rej, q1 = _snapshot(rs)
    assert n == n0 and rs.arm.mode == DISABLED and np.allclose(q1, q0)
    assert rej - rej0 == pair - pair0  # only a pair lost to a descheduled sender may count


def test_reset_fault_without_host_heartbeat_enable_needs_it(gw):
    rs, host = gw
    host.stop_heartbeat()
    assert _wait(lambda: rs.arm.mode == FAULT and rs.arm.fault == "host_lost", 2.0)
    host.arm_cmd(ARM_RESET)
    assert _wait(lambda: rs.arm.mode == DISABLED)
    host.arm_cmd(ARM_ENABLE)
    time.sleep(0.1)  # must stay disabled: no host heartbeat
    assert rs.arm.mode == DISABLED


# ---- host side: ARM_STATE pairing --------------------------------------------------------------
def test_set_pairer_rules():
    p = SetPairer(window=0.010)
    p.a(3, (1, 2, 3), 10.0)
    assert p.b(3, (4, 5, 6), 10.004) == (1, 2, 3, 4, 5, 6)
    p.a(4, (1, 2, 3), 10.0)
    assert p.b(4, (4, 5, 6), 10.011) is None  # late
    assert p.b(4, (4, 5, 6), 10.001) is None  # lone B (its A already used up)
    p.a(5, (1, 2, 3), 10.0)
    p.a(6, (1, 2, 3), 10.001)
    assert p.b(5, (4, 5, 6), 10.002) is None  # another A in between
    p.a(7, (1, 2, 3), 10.0)
    p.interrupt()
    assert p.b(7, (4, 5, 6), 10.001) is None
    p.a(8, (1, 2, 3), 10.0)
    assert p.b(9, (4, 5, 6), 10.001) is None  # other counter
    assert p.paired == 1 and p.discarded_b == 5


def test_can_arm_discards_late_state_half():
    with CanBench(with_igniter=False) as bench:
        rs, arm = bench.robot_side, bench.arm
        rs.faults.drop_tx.update({"ARM_STATE_A": 10**9, "ARM_STATE_B": 10**9})
        assert _wait(lambda: time.monotonic_ns() - arm._q_stamp > 60e6)  # state stream has stopped
        q0 = arm.state().joints.copy()
        pair0 = arm.rx_stats.rejected["pair"]
        a = {"J1_Position": 0.5, "J2_Position": 0.5, "J3_Position": -0.5, "Counter": 1}
        b = {"J4_Position": 0.1, "J5_Position": 0.1, "J6_Position": 0.1, "Counter": 1}
        t = time.time()
        arm._on_frame("ARM_STATE_A", a, t)
        arm._on_frame("ARM_STATE_B", b, t + 0.15)
        assert np.allclose(arm.state().joints, q0) and arm.rx_stats.rejected["pair"] == pair0 + 1
        arm._on_frame("ARM_STATE_A", a, t + 0.2)
        arm._on_frame("ARM_STATE_B", b, t + 0.202)
        assert np.allclose(arm.state().joints, [0.5, 0.5, -0.5, 0.1, 0.1, 0.1])
        rs.faults.drop_tx.clear()
