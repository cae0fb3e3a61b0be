"""The robot side of the CAN protocol on a python-can bus: Z1 arm gateway + igniter board.

`CanRobotSide` runs both simulated nodes (`ArmPlant`, `IgniterBoard`) in one background
thread on their own bus handle, so the real `CanArm` / `CanIgniter` adapters talk to them over
CAN exactly as on the robot. python-can `virtual` only connects buses of one process: start it
in the process (test, bench) that opens the adapters, on the same channel name.

Each node validates what it receives with its own `Receiver`: rejected frames — unknown 11-bit
ids, every 29-bit frame, remote/error frames, wrong DLC, bad checksum, bad counter — are counted
in that node's RxRejected by both nodes alike and never acted on; a rejected IGN_CMD while the
valve is open also shuts it and disarms the board. The gateway joins ARM_TARGET_A/B with
`SetPairer` (the B must follow its A directly, within 30 ms; an unpaired B is counted as 'pair').
Both consume the host heartbeats (arm: latched HOST_LOST fault; igniter: valve shut + disarmed)
and produce their own.

Fault hooks (`faults`): bus-off (node silent, deaf), dropped / corrupted / stale (repeated)
frames in either direction, silenced heartbeats; plant faults live on `arm.*` and
`board.hooks`.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from dataclasses import dataclass, field

import can
import numpy as np

from capm_field.robot_model import RobotModel
from drivers.can.codec import (
    ARM_DISABLE,
    ARM_ENABLE,
    ARM_FAULT_CODES,
    ARM_MODE_CODES,
    ARM_RESET,
    ARM_STOP,
    ARM_STOW,
    IGN_ARM,
    IGN_DISARM,
    IGN_EVENT_CODES,
    IGN_EXTINGUISH,
    IGN_FAULT_CODES,
    IGN_IGNITE,
    IGN_RESET,
    NMT_OPERATIONAL,
    NODE_ARM_GW,
    NODE_IGN_BOARD,
    PAIR_WINDOW_S,
    RESYNC_HOLD_S,
    Encoder,
    Receiver,
    SetPairer,
    database,
    node_acts_in_hold,
)
from drivers.can.config import CanBusConfig
from drivers.can.link import open_bus

from .sim_arm import FAULT, ArmPlant
from .sim_igniter import IgniterBoard, IgniterParams


@dataclass
class WireFaults:
    """Wire-level fault injection. Counts are 'next n frames'; names are DBC message names."""

    bus_off: bool = False  # robot side neither sends nor receives (both nodes)
    drop_rx: Counter = field(default_factory=Counter)  # name -> n incoming frames to drop
    drop_tx: Counter = field(default_factory=Counter)  # name -> n outgoing frames to drop
    corrupt_tx: Counter = field(default_factory=Counter)  # name -> n outgoing frames with a flipped bit
    stale_tx: Counter = field(default_factory=Counter)  # name -> n outgoing frames re-sent with the old counter
    silent_heartbeat: set = field(default_factory=set)  # heartbeat names not sent (node frozen)


@dataclass
class StreamLog:
    """What the arm gateway saw of the target stream (bench figures)."""

    applied: int = 0  # complete A+B pairs accepted
    incomplete: int = 0  # B without its A, late B, or A never completed: not applied
    first_ns: int | None = None
    last_ns: int | None = None
    max_gap_ns: int = 0
    gaps_ns: list = field(default_factory=list)
    record_gaps: bool = False


class CanRobotSide:
    def __init__(
        self,
        bus_cfg: CanBusConfig | None = None,
        robot: RobotModel | None = None,
        igniter: IgniterParams | None = None,
        tick: float = 0.002,
        heartbeat_period: float = 0.1,
        host_timeout: float = 0.3,
        state_period: float = 0.01,
        arm_status_period: float = 0.05,
        ign_status_period: float = 0.02,
        max_counter_jump: int = 3,
        pair_window: float = PAIR_WINDOW_S,
    ) -> None:
        self.robot = robot or RobotModel()
        self.arm = ArmPlant(self.robot)
        self.board = IgniterBoard(igniter)
        self.board.host_present = False  # until the host heartbeat is seen
        self.faults = WireFaults()
        self.stream = StreamLog()
        self.tick, self.hb_period, self.host_timeout = tick, heartbeat_period, host_timeout
        self.periods = {"state": state_period, "arm_status": arm_status_period, "ign_status": ign_status_period}
        self.enc = Encoder()
        # the nodes' receivers hold commands just after a resync (can.md rule 7: a stale burst)
        self.arm_rx = Receiver({"ARM_CMD", "ARM_TARGET_A", "ARM_TARGET_B", "HB_HOST_ARM"}, max_counter_jump,
                               RESYNC_HOLD_S, node_acts_in_hold)
        self.ign_rx = Receiver({"IGN_CMD", "HB_HOST_IGN"}, max_counter_jump, RESYNC_HOLD_S, node_acts_in_hold)
        db = database()
        self._ign_cmd_id = db.get_message_by_name("IGN_CMD").frame_id
        self._target_ids = {db.get_message_by_name(n).frame_id for n in ("ARM_TARGET_A", "ARM_TARGET_B")}
        self._last_tx: dict[str, can.Message] = {}
        self.targets = SetPairer(pair_window)
        self._host_arm_hb: float | None = None
        self._host_ign_hb: float | None = None
        self.lock = threading.RLock()  # held by the loop while it touches the plants
        self._stop = threading.Event()
        self._bus = open_bus(bus_cfg or CanBusConfig())
        self._thread = threading.Thread(target=self._run, name="can-robot-side", daemon=True)
        self._thread.start()

    # ---- loop --------------------------------------------------------------------------------
    def _run(self) -> None:
        now = time.monotonic()
        next_tick = now
        due = {"hb": now, "state": now, "arm_status": now, "ign_status": now}
        last_step = now
        self._last_arm_status: tuple | None = None
        self._last_ign_status: tuple | None = None
        while not self._stop.is_set():
            msg = self._bus.recv(timeout=max(0.0, next_tick - time.monotonic()))
            if msg is not None:
                with self.lock:
                    self._receive(msg)
                if time.monotonic() < next_tick:
                    continue
            self._drain()
            now = time.monotonic()
            next_tick = max(next_tick + self.tick, now)  # never burst after a stall
            with self.lock:
                self.arm.step(min(now - last_step, 0.05))
                last_step = now
                self.board.tick(now)
                self._watch_host(now)
                self._transmit(now, due)
        # frames on the bus before close() are received (a board's receiver is an interrupt): a
        # host's last EXTINGUISH, sent just before the bench stops, must not be lost with the thread
        self._drain()

    def _drain(self, limit: int = 512) -> None:
        """Take the frames already on the bus before the timer runs. A board's receiver is an
        interrupt and its timer is not late: when this thread was descheduled (a busy test
        machine), frames that arrived in time must not look late to the tick. Bounded, so a
        flood cannot starve the timer."""
        for _ in range(limit):
            msg = self._bus.recv(timeout=0.0)
            if msg is None:
                return
            with self.lock:
                self._receive(msg)

    def _watch_host(self, now: float) -> None:
        if self._host_arm_hb is not None and now - self._host_arm_hb > self.host_timeout:
            self._host_arm_hb = None
            if self.arm.enabled:
                self.arm.set_fault("host_lost")
        if self._host_ign_hb is not None and now - self._host_ign_hb > self.host_timeout:
            self._host_ign_hb = None
            self.board.host_lost(now)

    def _receive(self, msg: can.Message) -> None:
        f = self.faults
        if f.bus_off:
            return
        name = self._name(msg.arbitration_id)
        if name and f.drop_rx[name] > 0:
            f.drop_rx[name] -= 1
            return
        stamp = msg.timestamp or time.time()  # bus receive time (virtual: send time)
        # the node acts at the frame's arrival on the bus, not when this thread got to it
        now = time.monotonic() - min(max(0.0, time.time() - stamp), 1.0)
        std = not msg.is_extended_id
        before = self.arm_rx.stats.rejected_total
        got = self.arm_rx.accept(msg)
        if got:
            self._arm_frame(*got, now, stamp)
        elif std and msg.arbitration_id in self._target_ids and self.arm_rx.stats.rejected_total > before:
            self.targets.interrupt()  # a rejected target half between A and B breaks the set
        before = self.ign_rx.stats.rejected_total
        got = self.ign_rx.accept(msg)
        if got:
            self._ign_frame(*got, now)
        elif self.ign_rx.stats.rejected_total > before:
            # counted in RxRejected like the gateway's; a rejected IGN_CMD (11-bit id 0x120) while
            # the valve is open also shuts it and disarms the board; status goes out at once
            is_cmd = std and msg.arbitration_id == self._ign_cmd_id
            self.board.frame_rejected(now, command=is_cmd)
            if is_cmd:
                self._send_ign_status()

    def _arm_frame(self, name: str, sig: dict, now: float, stamp: float) -> None:
        a = self.arm
        if name == "HB_HOST_ARM":
            if sig["NmtState"] == NMT_OPERATIONAL:
                self._host_arm_hb = now
            else:  # a host that says it is not operational is lost, at once
                self._host_arm_hb = None
                if a.enabled:
                    a.set_fault("host_lost")
        elif name == "ARM_CMD":
            self.targets.interrupt()  # a command between the halves of a set discards the set
            cmd = int(sig["Command"])
            if cmd == ARM_ENABLE and self._host_arm_hb is not None:
                a.enable()
            elif cmd == ARM_DISABLE:
                a.disable()
            elif cmd == ARM_STOP:
                a.stop()
            elif cmd == ARM_STOW:
                a.stow()
            elif cmd == ARM_RESET:
                a.reset()  # accepted without the host heartbeat: it only ends in DISABLED
        elif name == "ARM_TARGET_A":
            if self.targets.pending:
                self.stream.incomplete += 1
            self.targets.a(int(sig["Counter"]), (sig["J1_Target"], sig["J2_Target"], sig["J3_Target"]), stamp)
        elif name == "ARM_TARGET_B":
            q6 = self.targets.b(int(sig["Counter"]), (sig["J4_Target"], sig["J5_Target"], sig["J6_Target"]), stamp)
            if q6 is None:  # lone, late or interleaved B: discarded and counted in RxRejected
                self.stream.incomplete += 1
                self.arm_rx.reject("pair")
                return
            a.set_target(np.array(q6))  # ignored (not counted) unless HOLDING / TRACKING
            s = self.stream
            t = time.monotonic_ns()
            if s.last_ns is not None:
                gap = t - s.last_ns
                s.max_gap_ns = max(s.max_gap_ns, gap)
                if s.record_gaps:
                    s.gaps_ns.append(gap)
            else:
                s.first_ns = t
            s.last_ns = t
            s.applied += 1

    def _ign_frame(self, name: str, sig: dict, now: float) -> None:
        b = self.board
        if name == "HB_HOST_IGN":
            if sig["NmtState"] == NMT_OPERATIONAL:
                self._host_ign_hb = now
                b.host_present = True
            else:  # not operational counts as lost, at once: valve shut, disarmed
                self._host_ign_hb = None
                b.host_lost(now)
                if self._ign_status() != self._last_ign_status:
                    self._send_ign_status()  # the trip's Event goes out before anything else
            return
        cmd = int(sig["Command"])
        if cmd == IGN_ARM:
            b.arm(now)
        elif cmd == IGN_DISARM:
            b.disarm(now)
        elif cmd == IGN_IGNITE:
            b.ignite(now)
        elif cmd == IGN_EXTINGUISH:
            b.extinguish(now)
        elif cmd == IGN_RESET:
            b.reset(now)
        self._send_ign_status()  # status on every command: the host sees changes at once

    # ---- tx ----------------------------------------------------------------------------------
    def _transmit(self, now: float, due: dict) -> None:
        if now >= due["hb"]:
            due["hb"] = now + self.hb_period
            self._send(self.enc.heartbeat("HB_ARM_GW", NODE_ARM_GW, self.hb_period))
            self._send(self.enc.heartbeat("HB_IGN_BOARD", NODE_IGN_BOARD, self.hb_period))
        if now >= due["state"]:
            due["state"] = now + self.periods["state"]
            q = self.arm.q
            c = self.enc.next_counter("ARM_STATE_A")
            self.enc.next_counter("ARM_STATE_B")
            self._send(self.enc.encode("ARM_STATE_A", {"J1_Position": q[0], "J2_Position": q[1], "J3_Position": q[2]}, counter=c))
            self._send(self.enc.encode("ARM_STATE_B", {"J4_Position": q[3], "J5_Position": q[4], "J6_Position": q[5]}, counter=c))
        arm_status = self._arm_status()
        if now >= due["arm_status"] or arm_status != self._last_arm_status:
            due["arm_status"] = now + self.periods["arm_status"]
            self._last_arm_status = arm_status
            keys = ("Mode", "Enabled", "Moving", "Stowed", "FaultCode", "RxRejected")
            self._send(self.enc.encode("ARM_STATUS", dict(zip(keys, arm_status))))
        if now >= due["ign_status"] or self._ign_status() != self._last_ign_status:
            due["ign_status"] = now + self.periods["ign_status"]
            self._send_ign_status()

    def _arm_status(self) -> tuple:
        a = self.arm
        mode = ARM_MODE_CODES[a.mode]
        return (mode, int(a.enabled), int(a.moving), int(a.stowed), ARM_FAULT_CODES.get(a.fault, 4) if a.mode == FAULT else 0,  # unknown code -> DRIVE_FAULT
                self.arm_rx.stats.rejected_total & 0xFF)

    def _ign_status(self) -> tuple:
        b = self.board
        return (int(b.armed), int(b.flame_on), int(b.igniting), int(b.fault is not None), round(b.fuel * 10000) / 100,
                IGN_FAULT_CODES.get(b.fault, 0), IGN_EVENT_CODES.get(b.event, 0), b.rejected & 0xFF)  # == ign_rx rejections

    def _send_ign_status(self) -> None:
        st = self._ign_status()
        self._last_ign_status = st
        keys = ("Armed", "FlameOn", "Igniting", "FaultLatched", "Fuel", "FaultCode", "Event", "RxRejected")
        self._send(self.enc.encode("IGN_STATUS", dict(zip(keys, st))))

    def _send(self, msg: can.Message) -> None:
        f = self.faults
        name = self._name(msg.arbitration_id)
        if f.bus_off or name in f.silent_heartbeat:
            return
        if f.drop_tx[name] > 0:
            f.drop_tx[name] -= 1
            return
        out = msg
        if f.stale_tx[name] > 0 and name in self._last_tx:
            f.stale_tx[name] -= 1
            out = self._last_tx[name]  # the previous frame again: repeated counter
        elif f.corrupt_tx[name] > 0:
            f.corrupt_tx[name] -= 1
            data = bytearray(msg.data)
            data[0] ^= 0x01
            out = can.Message(arbitration_id=msg.arbitration_id, data=bytes(data), is_extended_id=False)
        else:
            self._last_tx[name] = msg
        try:
            self._bus.send(out, timeout=0.01)
        except can.CanError:
            pass  # a real node would go error-passive; the host sees missing frames

    @staticmethod
    def _name(fid: int) -> str | None:
        try:
            return database().get_message_by_frame_id(fid).name
        except KeyError:
            return None

    # ---- control -----------------------------------------------------------------------------
    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(timeout=2.0)  # recv() waits at most one tick
        self._bus.shutdown()

    def __enter__(self) -> "CanRobotSide":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
