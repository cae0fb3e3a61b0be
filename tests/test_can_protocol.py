"""CAN protocol of the arm gateway and the igniter board: DBC round trips, counter/CRC
protection (bad frames rejected, counted, never acted on), igniter keep-alive cutoff, host and
gateway heartbeat loss, bus-off, clean shutdown, 500 Hz streaming. Real python-can `virtual`
buses and cantools with the shipped DBC; no mocks."""

from __future__ import annotations

import random
import re
import threading
import time
from pathlib import Path

import can
import numpy as np
import pytest

from capm_field.config import ArmConfig, RobotConfig
from capm_field.robot_model import RobotModel
from drivers.can.codec import (
    ARM_STOP,
    IGN_ARM,
    PAIR_WINDOW_S,
    IGN_EXTINGUISH,
    IGN_IGNITE,
    Encoder,
    Receiver,
    crc8_j1850,
    database,
    frame_checksum,
    is_protected,
)
from drivers.can.link import open_bus
from drivers.can_igniter import KEEPALIVE_BOUND_S
from drivers.interfaces import LinkLost
from sim_bench.can_rig import CanBench, RawHost
from sim_bench.drivers_bench import measure_can_link_loss, measure_can_stream, measure_igniter_cutoff
from keepalive_evidence import IgniteGaps
from waiting import wait_for


# ---- codec -----------------------------------------------------------------------------------
def test_crc8_sae_j1850_check_value():
    assert crc8_j1850(b"123456789") == 0x4B  # the catalogued check value of CRC-8/SAE-J1850


def test_checksum_covers_the_frame_id():
    data = bytes(8)
    assert frame_checksum(0x120, data) != frame_checksum(0x121, data)
    m = Encoder().encode("IGN_CMD", {"Command": IGN_IGNITE})
    moved = can.Message(arbitration_id=0x121, data=m.data, is_extended_id=False)  # same bytes as ARM_CMD
    rx = Receiver({"ARM_CMD"})
    assert rx.accept(moved) is None and rx.stats.rejected["checksum"] == 1


def test_dbc_round_trip_every_message():
    rng = random.Random(1)
    enc, db = Encoder(), database()
    for m in db.messages:
        rx = Receiver({m.name})
        for _ in range(20):
            sig = {}
            for s in m.signals:
                if s.name in ("Counter", "Checksum"):
                    continue
                lo, hi = s.minimum, s.maximum
                if s.scale == 1 and s.offset == 0:
                    sig[s.name] = rng.randint(int(lo), int(hi))
                else:
                    sig[s.name] = rng.uniform(lo, hi)
            got = rx.accept(enc.encode(m.name, sig))
            assert got is not None and got[0] == m.name, rx.stats
            for k, v in sig.items():
                assert got[1][k] == pytest.approx(v, abs=m.get_signal_by_name(k).scale / 2 + 1e-12), (m.name, k)
        assert rx.stats.rejected_total == 0
    assert all(is_protected(m) for m in db.messages if not m.name.startswith("HB_"))


def test_dbc_pair_window_comments_match_the_code():
    """The DBC is the single source of truth (can.md): its comments on the joint-set halves must
    state the pairing window the code applies (PAIR_WINDOW_S), and so must can.md."""
    window_ms = round(PAIR_WINDOW_S * 1000)
    db = database()
    for name in ("ARM_TARGET_A", "ARM_TARGET_B", "ARM_STATE_A", "ARM_STATE_B"):
        comment = db.get_message_by_name(name).comment or ""
        stated = [int(v) for v in re.findall(r"within (\d+) ms", comment)]
        assert stated and all(v == window_ms for v in stated), (name, comment, window_ms)
    doc = (Path(__file__).resolve().parents[1] / "docs" / "protocols" / "can.md").read_text()
    section = doc[doc.index("### Joint sets"):]
    section = section[:section.index("\n## ")]
    assert [int(v) for v in re.findall(r"within (\d+) ms", section)] == [window_ms], section


def _frame(enc: Encoder, counter: int | None = None) -> can.Message:
    return enc.encode("IGN_CMD", {"Command": IGN_IGNITE}, counter=counter)


def test_receiver_rejects_and_counts_bad_frames():
    enc, rx = Encoder(), Receiver({"IGN_CMD"})
    assert rx.accept(_frame(enc, 0)) is not None
    bad = bytearray(_frame(enc, 1).data)
    bad[0] ^= 0x04
    assert rx.accept(can.Message(arbitration_id=0x120, data=bytes(bad), is_extended_id=False)) is None
    assert rx.accept(_frame(enc, 0)) is None  # repeated counter (duplicate)
    assert rx.accept(_frame(enc, 1)) is not None
    assert rx.accept(_frame(enc, 14)) is None  # stale: behind the last one
    assert rx.accept(can.Message(arbitration_id=0x120, data=bytes(7), is_extended_id=False)) is None  # DLC 7
    assert rx.accept(can.Message(arbitration_id=0x7FF, data=bytes(8), is_extended_id=False)) is None  # unknown id
    assert rx.accept(can.Message(arbitration_id=0x121, data=bytes(8), is_extended_id=False)) is None  # not ours
    assert rx.accept(_frame(enc, 3)) is not None  # one frame lost (counter 2): accepted, loss counted
    r = rx.stats.rejected
    assert (r["checksum"], r["counter_repeated"], r["counter_sequence"], r["dlc"], r["unknown_id"]) == (1, 1, 1, 1, 1)
    assert rx.stats.accepted == 3 and rx.stats.lost == 1 and rx.stats.ignored == 1


def test_counter_resyncs_after_sender_restart():
    enc, rx = Encoder(), Receiver({"IGN_CMD"})
    for c in (5, 6, 7):
        assert rx.accept(_frame(enc, c)) is not None
    assert rx.accept(_frame(enc, 0)) is None  # restarted sender: first frame rejected
    assert rx.accept(_frame(enc, 1)) is not None  # follows the candidate: in sync again


def test_counter_documented_details():
    """docs/protocols/can.md: first frame any counter; only counter rejections resync; a checksum
    reject consumes no counter value; two recorded consecutive frames replay (no security)."""
    enc = Encoder()
    rx = Receiver({"IGN_CMD"})
    assert rx.accept(_frame(enc, 9)) is not None  # first frame after power-up: any counter
    bad = bytearray(_frame(enc, 3).data)
    bad[0] ^= 0x01
    assert rx.accept(can.Message(arbitration_id=0x120, data=bytes(bad), is_extended_id=False)) is None
    assert rx.accept(_frame(enc, 4)) is None  # the checksum reject at 3 is no resync candidate
    assert rx.accept(_frame(enc, 10)) is not None  # and consumed no value: 9 -> 10 still in step
    rec = [_frame(enc, 11), _frame(enc, 12)]
    for m in rec:
        assert rx.accept(m) is not None
    for c in (13, 14, 15):
        assert rx.accept(_frame(enc, c)) is not None
    assert rx.accept(rec[0]) is None  # a recorded frame replayed alone is rejected...
    assert rx.accept(rec[1]) is not None  # ...but the next recorded one follows it: resync accepts
    assert rx.stats.rejected["checksum"] == 1 and rx.stats.rejected["counter_sequence"] == 2


def test_extended_and_unknown_ids_rejected_with_their_reason():
    rx = Receiver({"ARM_CMD"})
    m = Encoder().encode("ARM_CMD", {"Command": 1})
    assert rx.accept(can.Message(arbitration_id=0x121, data=m.data, is_extended_id=True)) is None
    assert rx.accept(can.Message(arbitration_id=0x121, data=m.data)) is None  # python-can default: 29-bit
    assert rx.accept(can.Message(arbitration_id=0x555, data=bytes(8), is_extended_id=False)) is None
    assert rx.stats.rejected["extended_id"] == 2 and rx.stats.rejected["unknown_id"] == 1
    assert rx.accept(m) is not None  # the same bytes as an 11-bit frame


# ---- wire: bad frames are never acted on ------------------------------------------------------
def test_board_never_acts_on_bad_frames(raw):
    bench, host = raw
    board, rx = bench.robot_side.board, bench.robot_side.ign_rx
    good = host.enc.encode("IGN_CMD", {"Command": IGN_ARM})
    bad_crc = bytearray(good.data)
    bad_crc[7] ^= 0xFF
    host.send(can.Message(arbitration_id=0x120, data=bytes(bad_crc), is_extended_id=False))
    host.send(can.Message(arbitration_id=0x120, data=bytes(good.data[:6]), is_extended_id=False))  # short DLC
    assert host.wait_ign(lambda s: s["RxRejected"] == 2, 1.0)
    assert not board.armed and rx.stats.rejected["checksum"] == 1 and rx.stats.rejected["dlc"] == 1
    host.send(good)
    assert host.wait_ign(lambda s: s["Armed"] == 1, 1.0)
    host.ign(IGN_IGNITE)
    host.send(host.enc.encode("IGN_CMD", {"Command": IGN_IGNITE}, counter=0))  # stale counter
    assert host.wait_ign(lambda s: s["RxRejected"] == 3 and s["Armed"] == 0, 1.0)
    assert rx.stats.rejected["counter_sequence"] + rx.stats.rejected["counter_repeated"] == 1
    assert not board.valve_open  # the bad frame shut the valve the good IGNITE had opened
    assert not board.armed  # ... and disarmed the board (ARM again to burn)
    assert board.event == "bad_frame" and board.rejected == 3
    # the board reports its rejection count (waited for above)


def test_bad_frame_while_burning_extinguishes_at_once(raw):
    bench, host = raw
    host.light()  # ARM + keep-alives until lit
    host.ign(IGN_IGNITE)
    t_bad = host.send(can.Message(arbitration_id=0x120, data=bytes(8), is_extended_id=False))
    t_off = host.wait_ign(lambda s: s["FlameOn"] == 0, 0.5)
    assert t_off is not None and t_off - t_bad < 0.1
    assert host.wait_ign(lambda s: s["Armed"] == 0, 0.5)  # tripped: disarmed too


def test_adapters_reject_and_count_bad_status_frames():
    with CanBench() as bench:
        rs = bench.robot_side
        rs.faults.corrupt_tx.update({"IGN_STATUS": 3, "ARM_STATE_A": 2})
        rs.faults.stale_tx.update({"ARM_STATUS": 2})
        junk = RawHost(bench.bus, heartbeat_period=None)
        junk.send(can.Message(arbitration_id=0x555, data=bytes(8), is_extended_id=False))
        junk.send(can.Message(arbitration_id=0x221, data=bytes(3), is_extended_id=False))  # ARM_STATUS, DLC 3
        ia, aa = bench.igniter.rx_stats.rejected, bench.arm.rx_stats.rejected
        # the bad frames go out with the nodes' periodic frames (ARM_STATUS every 50 ms): ~0.1 s on a
        # quiet machine; a fixed 0.25 s left little for a descheduled sim thread. Exact counts below.
        wait_for(lambda: ia["checksum"] >= 3 and aa["checksum"] >= 2 and aa["counter_repeated"] >= 2 and aa["dlc"] >= 1, 3.0)
        time.sleep(0.05)  # nothing more may come: the injected counts are used up
        junk.close()
        assert ia["checksum"] == 3 and ia["unknown_id"] == 1
        assert aa["checksum"] == 2 and aa["counter_repeated"] == 2 and aa["unknown_id"] == 1 and aa["dlc"] == 1
        st = bench.arm.state()
        assert st.fault is None and np.all(np.isfinite(st.joints))
        assert bench.igniter.state().fault is None


# ---- wire: timing --------------------------------------------------------------------------------
def test_igniter_off_within_100ms_of_last_keepalive_on_the_wire():
    cut = measure_igniter_cutoff(trials=5, hold_s=0.05)
    # The board here is a Python thread, not the board's MCU: when other jobs starve the 2 cores
    # it ticks late. The median must meet the 100 ms bound; the max gets scheduling slack (the
    # firmware rule itself is pinned exactly on a simulated clock in test_can_board_contract.py).
    assert cut["board_ms"]["median"] <= 100.0, cut
    assert cut["board_ms"]["max"] <= 150.0, cut
    assert cut["host_seen_ms"]["max"] <= 300.0, cut  # + status delivery latency (sanity bound only)


def test_heartbeat_loss_detected_within_consumer_timeout():
    for _ in range(3):  # a late max (244 ms with this process stopped ~50 ms) is measured again
        ll = measure_can_link_loss(trials=3, timeout_s=0.2)
        assert 200.0 <= ll["median"], ll  # never before the consumer timeout
        if ll["max"] <= 200.0 + 40.0:  # consumer timeout + scheduling
            break
    assert ll["max"] <= 200.0 + 40.0, ll


def test_gateway_heartbeat_loss_raises_link_lost_then_recovers():
    with CanBench(with_igniter=False, heartbeat_timeout=0.2) as bench:
        rs, arm = bench.robot_side, bench.arm
        rs.faults.silent_heartbeat.add("HB_ARM_GW")
        time.sleep(0.3)
        with pytest.raises(LinkLost):
            arm.move_joints(np.array([0.2, 0.5, -0.5, 0, 0, 0]), timeout=2.0)
        rs.faults.silent_heartbeat.clear()
        # the next heartbeat goes out within its 0.1 s period: 0.15 s left 50 ms for a loaded machine
        assert wait_for(lambda: arm.link.ok, 2.0)
        assert arm.state().fault is None


def test_host_loss_shuts_valve_and_disarms(raw):
    bench, host = raw
    host.ign(IGN_ARM)
    assert host.wait_ign(lambda s: s["Armed"] == 1, 1.0)
    host.stop_heartbeat()  # host frozen except for keep-alives (bug): the board must still stop
    t_end = time.monotonic() + 0.6
    while time.monotonic() < t_end:
        host.ign(IGN_IGNITE)
        time.sleep(0.04)
    b = bench.robot_side.board
    assert not b.valve_open and not b.armed and not b.host_present


def test_bus_off_during_ignite_raises_link_lost_and_flame_off():
    with CanBench(heartbeat_timeout=0.2) as bench:
        ign, rs = bench.igniter, bench.robot_side
        ign.arm(timeout=1.0)
        t_off = threading.Timer(0.3, lambda: setattr(rs.faults, "bus_off", True))
        t_off.start()
        with pytest.raises(LinkLost):
            ign.ignite(2.0, lambda: True, timeout=3.0)
        t_off.join()
        assert not rs.board.flame_on and not rs.board.valve_open  # keep-alives never reached it
        # the last status heard (flame on) is stale: by the board's keep-alive trip, off and disarmed
        # KEEPALIVE_BOUND_S after the last IGNITE sent
        time.sleep(KEEPALIVE_BOUND_S)
        seen = ign._status
        st = ign.state()
        assert st.fault == "link_lost" and not st.flame_on and not st.armed, (st, seen)
        with pytest.raises(LinkLost):
            bench.arm.move_joints(np.zeros(6), timeout=1.0)


def test_clean_shutdown_no_threads_left_and_no_hang():
    import can.interfaces.virtual as virt

    base = threading.active_count()
    t0 = time.monotonic()
    for _ in range(3):
        bench = CanBench()
        bench.igniter.arm(timeout=1.0)
        th = threading.Thread(target=lambda b=bench: _ignite_quiet(b), daemon=True)
        th.start()
        time.sleep(0.2)
        bench.close()  # while ignite() runs in another thread
        th.join(2.0)
        assert not th.is_alive()
        assert not bench.robot_side.board.valve_open
        bench.close()  # idempotent
    assert time.monotonic() - t0 < 5.0
    time.sleep(0.1)
    assert threading.active_count() <= base
    assert not any(ch.startswith("capm-") and q for ch, q in virt.channels.items())


def _close_after(link, late: threading.Event) -> threading.Event:
    """Make `link.close()` wait (≤ 0.5 s) for `late`, the held-up send of a test, so that send goes
    out before the link is shut; returns the event set once it is shut."""
    real_close, closed = link.close, threading.Event()

    def close():
        late.wait(0.5)
        real_close()
        closed.set()

    link.close = close
    return closed


def test_no_ignite_keepalive_follows_close_extinguish():
    """close() while ignite() runs in another thread: the EXTINGUISH that close() sends is the host's
    last word. An IGNITE keep-alive held up between the adapter's 'closed?' check and its send (a
    descheduled thread, as on a busy machine) must not go out after it. Made certain here: that
    send waits for close()'s EXTINGUISH, and returns only once the link is closed, so that ignite()'s
    own EXTINGUISH on the way out cannot be sent any more. Before the fix the IGNITE was the last
    command sent and the bench board's valve stayed open (a CI run, under load)."""
    db = database()
    with CanBench() as bench:
        ign = bench.igniter
        ign.arm(timeout=1.0)
        sent: list[int] = []
        real_send = ign.link.send
        hold, held, extinguished, late = (threading.Event() for _ in range(4))
        closed = _close_after(ign.link, late)

        def send(msg):
            cmd = None
            if db.get_message_by_frame_id(msg.arbitration_id).name == "IGN_CMD":
                cmd = int(db.decode_message(msg.arbitration_id, msg.data, decode_choices=False)["Command"])
            stalled = cmd == IGN_IGNITE and hold.is_set() and not held.is_set()
            if stalled:
                held.set()
                extinguished.wait(0.5)  # descheduled after the check, until close() has sent EXTINGUISH
            if cmd == IGN_EXTINGUISH:
                extinguished.set()
            ok = real_send(msg)
            if cmd is not None and ok:  # (sent: on the bus)
                sent.append(cmd)
            if stalled:
                late.set()
                closed.wait(1.0)
            return ok

        ign.link.send = send
        th = threading.Thread(target=lambda: _ignite_quiet(bench), daemon=True)
        th.start()
        assert wait_for(lambda: IGN_IGNITE in sent, 2.0)
        hold.set()
        assert held.wait(2.0)
        ign.close()
        th.join(3.0)
        assert not th.is_alive()
        last_off = len(sent) - 1 - sent[::-1].index(IGN_EXTINGUISH)
        assert IGN_IGNITE not in sent[last_off:], sent[-6:]
        assert wait_for(lambda: not bench.robot_side.board.valve_open, 1.0)


def test_no_arm_target_follows_close_stop():
    """close() while a move streams in another thread: close()'s STOP is the host's last word to
    the gateway. A target set held up between the stream's 'closed?' check and its send must not
    go out after the STOP: the gateway takes a set in HOLDING and goes back to TRACKING. Made
    certain as for the igniter: that send waits (up to 0.5 s) for close()'s STOP, and returns only
    once the link is closed. Before the fix the last frames were [STOP, TARGET_A, TARGET_B]."""
    db = database()
    names = {db.get_message_by_name(n).frame_id: n for n in ("ARM_CMD", "ARM_TARGET_A", "ARM_TARGET_B")}
    with CanBench() as bench:
        arm = bench.arm
        sent: list[str] = []
        real_send = arm.link.send
        hold, held, stopped, late = (threading.Event() for _ in range(4))
        _close_after(arm.link, late)

        def send(msg):
            name = names.get(msg.arbitration_id)
            if name == "ARM_CMD":
                cmd = int(db.decode_message(msg.arbitration_id, msg.data, decode_choices=False)["Command"])
                name = "STOP" if cmd == ARM_STOP else f"CMD{cmd}"
            stalled = name == "ARM_TARGET_A" and hold.is_set() and not held.is_set()
            if stalled:
                held.set()
                stopped.wait(0.5)  # descheduled after the check, until close() has sent STOP
            ok = real_send(msg)
            if name is not None and ok:
                sent.append(name)
            if name == "STOP":
                stopped.set()
            if stalled:
                late.set()
            return ok

        arm.link.send = send
        q = np.array(bench.robot.cfg.arm.stow_joints) + np.array([0.6, 0.3, -0.3, 0.2, 0.2, 0.2])
        th = threading.Thread(target=lambda: _move_quiet(arm, q), daemon=True)
        th.start()
        assert wait_for(lambda: "ARM_TARGET_B" in sent, 3.0)
        hold.set()
        assert held.wait(2.0)
        arm.close()
        th.join(3.0)
        assert not th.is_alive()
        last_stop = len(sent) - 1 - sent[::-1].index("STOP")
        assert sent[last_stop + 1:] == [], sent[-6:]


def _move_quiet(arm, q) -> None:
    try:
        arm.move_joints(q, timeout=10.0)
    except Exception:  # noqa: BLE001 - LinkLost once closed is the expected outcome
        pass


def _ignite_quiet(bench: CanBench) -> None:
    try:
        bench.igniter.ignite(5.0, lambda: True, timeout=6.0)
    except Exception:  # noqa: BLE001 - LinkLost once closed is the expected outcome
        pass


def test_stream_500hz_short():
    brisk = RobotModel(RobotConfig(arm=ArmConfig(max_joint_speed=3.0)))  # shorter move to the start pose
    rates = []
    for _ in range(3):
        with CanBench(robot=brisk, with_igniter=False) as bench:
            pairs = _TargetPairs(bench.bus)
            try:
                s = measure_can_stream(1.5, bench)
            finally:
                pairs.close()
        assert s["reordered"] == 0 and s["fault"] is None, s
        # A pair is lost only when our host sent its B more than PAIR_WINDOW_S after its A (this
        # process descheduled between the halves, seen on the bus); with prompt pairs none is.
        late = pairs.late_b()
        assert s["lost"] <= late and (s["incomplete_pairs"] == 0 or late > 0), (s, late)
        assert s["rate_hz"] <= 505.0, s  # late ticks are skipped, never burst
        rates.append(s["rate_hz"])
        if s["rate_hz"] >= 350.0:
            break
    # Rate is a real-time figure: on a quiet machine ~500 Hz (bench-drivers, slow test); a
    # CPU-starved run streams slower (280 Hz with one busy thread in this process). Only a rate
    # below 350 Hz on three runs in a row fails; in every run each lost pair is a late B on the bus.
    assert max(rates) >= 350.0, (rates, s)


class _TargetPairs(can.Listener):
    """Bus times of the host's ARM_TARGET_A/B frames on a bench bus: how many B halves went out
    more than PAIR_WINDOW_S after the A before them (or with no A before them)."""

    def __init__(self, bus_cfg) -> None:
        db = database()
        self._a = db.get_message_by_name("ARM_TARGET_A").frame_id
        self._b = db.get_message_by_name("ARM_TARGET_B").frame_id
        self.frames: list[tuple[int, float]] = []
        self.bus = open_bus(bus_cfg)
        self.notifier = can.Notifier(self.bus, [self], timeout=0.05)

    def on_message_received(self, msg: can.Message) -> None:
        if not msg.is_extended_id and msg.arbitration_id in (self._a, self._b):
            self.frames.append((msg.arbitration_id, msg.timestamp))

    def late_b(self) -> int:
        late, t_a = 0, None
        for fid, t in list(self.frames):
            if fid == self._a:
                t_a = t
            else:
                late += t_a is None or t - t_a > PAIR_WINDOW_S
                t_a = None
        return late

    def close(self) -> None:
        self.notifier.stop(timeout=1.0)
        self.bus.shutdown()


@pytest.mark.slow
def test_stream_500hz_60s():
    s = measure_can_stream(60.0)
    assert s["lost"] == 0 and s["reordered"] == 0 and s["incomplete_pairs"] == 0 and s["fault"] is None, s
    # on a loaded shared CPU the streamer skips (never bursts) ticks it was >10 ms late for
    assert 480.0 <= s["rate_hz"] <= 505.0, s


def test_blind_host_stops_arm_and_flame():
    """Status frames lost while the heartbeat continues: the host stops rather than guess."""
    with CanBench(heartbeat_timeout=0.3) as bench:
        rs = bench.robot_side
        ign = bench.igniter
        gaps = IgniteGaps(bench.bus)
        try:
            for _ in range(3):  # a keep-alive trip first is retried only on the bus's evidence of a host stall
                ign.arm(timeout=1.0)
                gaps.clear()
                drop = threading.Timer(0.3, lambda: rs.faults.drop_tx.update({"IGN_STATUS": 10_000}))
                drop.start()
                r = ign.ignite(1.0, lambda: True, timeout=2.0)
                drop.join()
                if r.reason != "keepalive_timeout":
                    break
                assert gaps.host_silence() > rs.board.p.keepalive_timeout, (r, gaps.host_silence())
                rs.faults.drop_tx.clear()
                assert wait_for(lambda: ign.state().stamp_ns > time.monotonic_ns() - 50e6, 1.0)  # status again
        finally:
            gaps.close()
        assert not r.ok and r.reason == "status_stale", r
        time.sleep(0.1)
        assert not rs.board.flame_on and not rs.board.valve_open
        threading.Timer(0.2, lambda: rs.faults.drop_tx.update({"ARM_STATE_B": 10_000})).start()
        r = bench.arm.move_joints(np.array([0.6, 1.2, -1.2, 0.3, 0.4, 0.2]), timeout=5.0)
        assert not r.ok and r.reason == "state_stale"
        rs.faults.drop_tx.clear()


def test_interlock_denies_a_hold_once_the_arm_state_goes_stale():
    """Gateway heartbeat alive but its joint state and status stop during a flame hold (the arm may
    sag or latch a fault this host never hears of): `CanArm.state()` says `state_stale`, the
    ignition interlock denies and the flame goes out; the fault clears when state frames resume."""
    from capm_field.config import TaskConfig
    from drivers.interfaces import DriverSet
    from mission.interlock import IgnitionInterlock
    from sim_bench.sim_body import SimBodyDriver

    robot = RobotModel()
    with CanBench(robot=robot) as bench:
        rs, body = bench.robot_side, SimBodyDriver()
        assert bench.arm.move_joints(np.array([0.0, 1.6, -0.5, 0.0, 0.6, 0.0]), 10.0).ok
        T = robot.T_field_base(body.state().pose) @ bench.arm.state().nozzle_pose
        X, ax = T[:3, 3], T[:3, 0]
        aim = X + (-X[2] / ax[2]) * ax  # where the nozzle points on the ground
        d2 = float(np.sum((aim - X) ** 2))
        interlock = IgnitionInterlock(DriverSet(body=body, arm=bench.arm, igniter=bench.igniter, camera=None), robot,
                                      TaskConfig(eps_min=0.9 * d2, eps_max=1.1 * d2), (float(aim[0]), float(aim[1])))
        interlock.anchor()
        assert interlock.check().ok, interlock.check().reasons
        bench.igniter.arm(1.0)
        blind: list[float] = []

        def go_blind() -> None:
            with rs.lock:
                rs.faults.drop_tx.update({n: 10**9 for n in ("ARM_STATE_A", "ARM_STATE_B", "ARM_STATUS")})
                blind.append(time.monotonic())

        threading.Timer(0.3, go_blind).start()
        r = bench.igniter.ignite(3.0, interlock.permit, 10.0)
        out = time.monotonic()
        assert not r.ok and r.reason == "permit_dropped", r
        assert blind and out - blind[0] < 0.25 + 0.5, out - blind[0]  # state_timeout, + scheduling slack
        assert bench.arm.state().fault == "state_stale" and "arm_fault:state_stale" in interlock.check().reasons
        assert wait_for(lambda: not rs.board.flame_on and not rs.board.valve_open, 0.5)
        with rs.lock:
            rs.faults.drop_tx.clear()
        assert wait_for(lambda: bench.arm.state().fault is None, 1.0)  # not latched: fresh state clears it
