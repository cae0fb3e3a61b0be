"""Host process restart on a running gateway / board (docs/protocols/can.md, "Host start-up").

The gateway and the board keep their counter state while the host restarts; a new `CanIgniter`
/ `CanArm` starts its counters at 0, so without the start-up sync the node rejected its first
command (counter rule) and `arm()` / `reset()` timed out. The new host synchronises with NOPs and
its first command is accepted, applied once; stale and replayed frames are still rejected.
Real python-can `virtual` bus, the bench's board/gateway model, real adapters."""

from __future__ import annotations

import itertools
import time

import can
import numpy as np

from drivers.can.codec import ARM_ENABLE, ARM_RESET, IGN_ARM, IGN_DISARM, _CounterCheck
from drivers.can.config import CanArmConfig, CanBusConfig, CanIgniterConfig
from drivers.can.link import SYNC_NOPS, open_bus
from drivers.can_arm import CanArm
from drivers.can_igniter import CanIgniter
from sim_bench.can_rig import CanBench
from sim_bench.sim_arm import DISABLED, FAULT, HOLDING
from waiting import wait_for

IGN_CMD_ID, ARM_CMD_ID = 0x120, 0x121
MAX_JUMP = 3


class _Recorder(can.Listener):
    """Records the frames of `ids` on the bench bus (to find counters, and to replay frames)."""

    def __init__(self, bus_cfg: CanBusConfig, ids: set[int]) -> None:
        self.ids, self.frames = ids, []
        self.bus = open_bus(bus_cfg)
        self.notifier = can.Notifier(self.bus, [self], timeout=0.05)

    def on_message_received(self, msg: can.Message) -> None:
        if not msg.is_extended_id and msg.arbitration_id in self.ids:
            self.frames.append(msg)

    def mark(self) -> int:
        time.sleep(0.05)  # frames already sent have been delivered
        return len(self.frames)

    def replay(self, msg: can.Message) -> None:
        self.bus.send(can.Message(arbitration_id=msg.arbitration_id, data=bytes(msg.data), is_extended_id=False))

    def close(self) -> None:
        self.notifier.stop(timeout=1.0)
        self.bus.shutdown()


def _ctr(msg: can.Message) -> int:
    return msg.data[6] & 0x0F


def _cmd(msg: can.Message) -> int:
    return msg.data[0]


def _in_step(counter: int, last: int) -> bool:
    """True if a receiver whose last accepted counter is `last` accepts `counter` as in sequence."""
    return 1 <= ((counter - last) & 0x0F) <= MAX_JUMP


def _counter_rejects(rx) -> int:
    return rx.stats.rejected["counter_sequence"] + rx.stats.rejected["counter_repeated"]


# ---- the argument behind the procedure, exhaustively on the receiver's counter check -----------
def test_three_nops_bring_any_receiver_state_in_step():
    """Whatever the receiver saw before (any last counter, any remembered resync candidate, or
    nothing), three consecutive frames from any start counter are rejected at most once, and
    the frame after them is accepted: RxRejected rising by <= 1 over the NOPs means in step."""
    states = [(None, None)] + [(last, cand) for last in range(16) for cand in [None, *range(16)]]
    for (last, cand), c in itertools.product(states, range(16)):
        chk = _CounterCheck(MAX_JUMP)
        chk.last, chk.candidate = last, cand
        rejected = [chk.check((c + k) & 0x0F)[0] for k in range(SYNC_NOPS)]
        assert sum(r is not None for r in rejected) <= 1 and rejected[-1] is None, (last, cand, c, rejected)
        assert chk.check((c + SYNC_NOPS) & 0x0F)[0] is None, (last, cand, c)  # the first real command


# ---- wire: igniter board ------------------------------------------------------------------------
def test_restarted_igniter_host_arms_on_its_first_command_and_stale_frames_stay_rejected():
    with CanBench(with_arm=False) as bench:
        rs = bench.robot_side
        rec = _Recorder(bench.bus, {IGN_CMD_ID})
        try:
            ig1 = bench.igniter
            ig1.arm(1.0)
            ig1.disarm()
            ig1.close()  # the host process goes away; the board keeps running
            bench.igniter = None
            assert wait_for(lambda: not rs.board.host_present, 2.0)  # past the board's host timeout
            last_old = _ctr(rec.frames[rec.mark() - 1])
            n0, rej0 = len(rec.frames), _counter_rejects(rs.ign_rx)

            ig2 = bench.igniter = CanIgniter(CanIgniterConfig(bus=bench.bus))  # the restarted host
            ig2.arm(1.0)  # its first command: accepted (it timed out before the start-up sync)
            assert rs.board.armed and ig2.state().armed and ig2.sync_rounds == 1

            new = rec.frames[n0:rec.mark()]
            assert not _in_step(_ctr(new[0]), last_old)  # the case under test: the board rejected it
            assert _counter_rejects(rs.ign_rx) - rej0 == 1  # ...that NOP, and only it
            assert [_cmd(m) for m in new] == [0] * SYNC_NOPS + [IGN_ARM]  # ARM sent (and applied) once

            # the counter check still guards the board: stale and duplicated frames are rejected
            ig2.disarm()
            sent = rec.frames[n0:rec.mark()]
            arm_frame = next(m for m in sent if _cmd(m) == IGN_ARM)
            disarm_frame = sent[-1]
            assert _cmd(disarm_frame) == IGN_DISARM and not _in_step(_ctr(arm_frame), _ctr(disarm_frame))
            assert wait_for(lambda: not rs.board.armed, 1.0)
            rej1 = _counter_rejects(rs.ign_rx)
            rec.replay(arm_frame)  # an ARM recorded earlier: stale now
            rec.replay(disarm_frame)  # the last frame again: a duplicate
            assert wait_for(lambda: _counter_rejects(rs.ign_rx) == rej1 + 2, 1.0)
            time.sleep(0.05)
            assert not rs.board.armed  # never acted on
            ig2.arm(1.0)  # and the host is still in step afterwards
            assert rs.board.armed
        finally:
            rec.close()


# ---- wire: arm gateway --------------------------------------------------------------------------
def test_restarted_arm_host_resets_host_lost_on_its_first_command_and_stale_enable_is_rejected():
    with CanBench(with_igniter=False) as bench:
        rs = bench.robot_side
        rec = _Recorder(bench.bus, {ARM_CMD_ID})
        try:
            arm1 = bench.arm
            stow = np.array(bench.robot.cfg.arm.stow_joints)
            assert arm1.move_joints(stow + np.array([0.05, 0.05, 0, 0, 0, 0]), 5.0).ok
            arm1.close()  # STOP; the host process goes away, the gateway keeps running
            bench.arm = None
            assert wait_for(lambda: rs.arm.mode == FAULT and rs.arm.fault == "host_lost", 2.0)
            old = rec.frames[:rec.mark()]
            enable_old = next(m for m in old if _cmd(m) == ARM_ENABLE)
            n0, rej0 = len(rec.frames), _counter_rejects(rs.arm_rx)

            arm2 = bench.arm = CanArm(CanArmConfig(bus=bench.bus), robot=bench.robot)  # restarted host
            assert arm2.fault == "host_lost"
            arm2.reset(1.0)  # its first command: accepted (it timed out before the start-up sync)
            assert rs.arm.mode == DISABLED and arm2.fault is None and arm2.sync_rounds == 1

            new = rec.frames[n0:rec.mark()]
            assert not _in_step(_ctr(new[0]), _ctr(old[-1]))  # the case under test
            assert _counter_rejects(rs.arm_rx) - rej0 == 1
            assert [_cmd(m) for m in new] == [0] * SYNC_NOPS + [ARM_RESET]  # RESET_FAULT sent once

            # the previous host's ENABLE replayed: out of sequence, rejected, never acted on
            assert not _in_step(_ctr(enable_old), _ctr(new[-1]))
            rej1 = _counter_rejects(rs.arm_rx)
            rec.replay(enable_old)
            assert wait_for(lambda: _counter_rejects(rs.arm_rx) == rej1 + 1, 1.0)
            time.sleep(0.05)
            assert rs.arm.mode == DISABLED

            assert arm2.move_joints(stow + np.array([0.0, 0.1, 0, 0, 0, 0]), 5.0).ok  # and it moves
        finally:
            rec.close()


def test_quick_host_restart_while_the_arm_holds_moves_on_the_first_call():
    """Restart faster than the host timeout: the gateway still HOLDING (no HOST_LOST). The move
    needs no ENABLE; its first target set may be rejected by the counter rule (documented), the
    stream carries on and the move arrives."""
    with CanBench(with_igniter=False) as bench:
        rs = bench.robot_side
        stow = np.array(bench.robot.cfg.arm.stow_joints)
        assert bench.arm.move_joints(stow + np.array([0.05, 0.05, 0, 0, 0, 0]), 5.0).ok
        bench.arm.close()
        bench.arm = None
        arm2 = bench.arm = CanArm(CanArmConfig(bus=bench.bus), robot=bench.robot)
        assert rs.arm.mode in (HOLDING, "tracking") and rs.arm.fault is None
        rej0 = _counter_rejects(rs.arm_rx)
        r = arm2.move_joints(stow + np.array([0.1, 0.1, 0, 0, 0, 0]), 5.0)
        assert r.ok and rs.arm.fault is None, r
        assert _counter_rejects(rs.arm_rx) - rej0 <= 2  # at most the first set's two halves
