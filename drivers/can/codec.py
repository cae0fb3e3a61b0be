"""Encode/decode capm frames with cantools and protect them with a rolling counter + CRC-8.

cantools packs the signals from `capm.dbc`; it does not compute counters or checksums, so this
module does (docs/protocols/can.md is the reference for a gateway author):

* Counter: 4 bits, byte 6 bits 0-3, +1 mod 16 per transmitted frame of one id (the two halves
  of a joint-target or joint-state set share one value).
* Checksum: byte 7 = CRC-8 SAE J1850 (poly 0x1D, init 0xFF, xorout 0xFF, no reflection) over
  ``[id & 0xFF, (id >> 8) & 0xFF, b0 .. b7]`` with b7 (the checksum itself) set to 0.
  Including the id stops a payload that is valid for one frame being accepted as another.

Receivers (`Receiver`) reject — and count, never act on — unknown ids, 29-bit (extended)
frames, remote and error frames, CAN FD frames, wrong DLC, bad checksum, a signal outside its
DBC range, repeated counters and out-of-sequence (stale / reordered) counters. The counter and CRC catch faults of an honest sender (lost,
repeated, stale, reordered, corrupted frames); they are no protection against a deliberate
sender on the bus (a recorded pair of consecutive frames replays through the resync rule).
`SetPairer` joins the A and B halves of a joint set (targets, states).
"""

from __future__ import annotations

import threading
import time
from collections import Counter as _Tally
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import can
import cantools

DBC_PATH = Path(__file__).with_name("capm.dbc")

# node ids (CANopen style: heartbeat id = 0x700 + node id)
NODE_HOST_ARM = 0x01
NODE_HOST_IGN = 0x02
NODE_ARM_GW = 0x11
NODE_IGN_BOARD = 0x12
HEARTBEAT_BASE = 0x700

NMT_BOOTUP, NMT_STOPPED, NMT_OPERATIONAL, NMT_PRE_OPERATIONAL = 0, 4, 5, 127

# command / code tables (mirrors the DBC VAL_ tables)
IGN_NOP, IGN_ARM, IGN_DISARM, IGN_IGNITE, IGN_EXTINGUISH, IGN_RESET = range(6)
ARM_NOP, ARM_ENABLE, ARM_DISABLE, ARM_STOP, ARM_STOW, ARM_RESET = range(6)
IGN_FAULTS = {0: None, 1: "ignition_failed", 2: "flame_out", 3: "fuel_empty", 4: "hardware"}
IGN_FAULT_CODES = {v: k for k, v in IGN_FAULTS.items() if v}
IGN_EVENTS = {0: None, 1: "keepalive_timeout", 2: "bad_frame", 3: "host_lost", 4: "not_armed", 5: "extinguished"}
IGN_EVENT_CODES = {v: k for k, v in IGN_EVENTS.items() if v}
ARM_MODES = {0: "disabled", 1: "holding", 2: "tracking", 3: "stowing", 4: "fault"}
ARM_MODE_CODES = {v: k for k, v in ARM_MODES.items()}
ARM_FAULTS = {0: None, 1: "target_out_of_range", 2: "target_jump", 3: "host_lost", 4: "drive_fault", 5: "estop", 6: "overcurrent"}
ARM_FAULT_CODES = {v: k for k, v in ARM_FAULTS.items() if v}

COUNTER_BYTE, CHECKSUM_BYTE = 6, 7


# ---- CRC-8 SAE J1850 -------------------------------------------------------------------------
def _crc_table() -> list[int]:
    table = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = ((c << 1) ^ 0x1D) & 0xFF if c & 0x80 else (c << 1) & 0xFF
        table.append(c)
    return table


_TABLE = _crc_table()


def crc8_j1850(data: bytes | bytearray) -> int:
    """CRC-8 SAE J1850: poly 0x1D, init 0xFF, xorout 0xFF. check("123456789") == 0x4B."""
    c = 0xFF
    for b in data:
        c = _TABLE[c ^ b]
    return c ^ 0xFF


def frame_checksum(frame_id: int, data: bytes | bytearray) -> int:
    """Checksum of an 8-byte protected frame: CRC over id (LE, 2 bytes) + payload with byte 7 = 0."""
    buf = bytearray((frame_id & 0xFF, (frame_id >> 8) & 0xFF)) + bytearray(data)
    buf[2 + CHECKSUM_BYTE] = 0
    return crc8_j1850(buf)


# ---- database --------------------------------------------------------------------------------
@lru_cache(maxsize=1)
def database() -> cantools.database.can.Database:
    return cantools.database.load_file(str(DBC_PATH))


def is_protected(msg_def) -> bool:
    names = {s.name for s in msg_def.signals}
    return "Counter" in names and "Checksum" in names


class Encoder:
    """Builds protected frames; keeps one rolling counter per frame id (thread-safe)."""

    def __init__(self) -> None:
        self.db = database()
        self._counters: dict[int, int] = {}
        self._lock = threading.Lock()

    def next_counter(self, name: str) -> int:
        fid = self.db.get_message_by_name(name).frame_id
        with self._lock:
            c = self._counters.get(fid, 15)
            c = (c + 1) & 0x0F
            self._counters[fid] = c
            return c

    def encode(self, name: str, signals: dict, counter: int | None = None) -> can.Message:
        """Encode `signals` (physical values); Counter/Checksum are filled in here.

        `counter=None` takes the next value of this id's counter; pass one explicitly to give
        the two halves of a target/state set the same value (or to inject faults in tests).
        """
        m = self.db.get_message_by_name(name)
        sig = dict(signals)
        if is_protected(m):
            sig["Counter"] = self.next_counter(name) if counter is None else counter & 0x0F
            sig["Checksum"] = 0
        data = bytearray(m.encode(sig, scaling=True, strict=True))
        if is_protected(m):
            data[CHECKSUM_BYTE] = frame_checksum(m.frame_id, data)
        return can.Message(arbitration_id=m.frame_id, data=bytes(data), is_extended_id=False)

    def heartbeat(self, name: str, node_id: int, period: float, state: int = NMT_OPERATIONAL) -> can.Message:
        return self.encode(name, {"NmtState": state, "NodeId": node_id, "PeriodMs": int(round(period * 1000))})


# ---- reception -------------------------------------------------------------------------------
REJECT_REASONS = (
    "unknown_id",  # 11-bit id not in the DBC
    "extended_id",  # any 29-bit frame (the protocol is CAN 2.0A only)
    "remote_or_error",
    "fd",  # a CAN FD frame (the protocol is classic CAN only)
    "dlc",
    "checksum",
    "counter_repeated",
    "counter_sequence",
    "decode",
    "range",  # a signal outside its DBC [min|max] (e.g. Command 200, Fuel 600 %): never acted on
    "pair",  # counted by the set consumer (`SetPairer`): a B half without its A (lone, late, interleaved)
)


@dataclass
class RxStats:
    accepted: int = 0
    lost: int = 0  # frames missing according to counter steps > 1
    ignored: int = 0  # known ids meant for another node
    rejected: _Tally = field(default_factory=_Tally)

    @property
    def rejected_total(self) -> int:
        return sum(self.rejected.values())

    def as_dict(self) -> dict:
        return {"accepted": self.accepted, "lost": self.lost, "ignored": self.ignored, "rejected": dict(self.rejected)}


class _CounterCheck:
    """AUTOSAR-E2E-like counter check for one id: step 1 ok, 2..max_jump ok with loss,
    0 = repeated, anything else = out of sequence. The first frame ever seen is accepted with
    any counter. Resync after a sender restart: a counter-rejected frame's counter becomes the
    candidate, and a frame that follows the candidate by 1 is accepted (frames rejected earlier,
    by DLC or checksum, never reach this check: they neither resync nor consume a value)."""

    def __init__(self, max_jump: int) -> None:
        self.max_jump = max_jump
        self.last: int | None = None
        self.candidate: int | None = None
        self.synced_at: float | None = None  # when the counter was last taken up afresh (first frame, resync)

    def check(self, c: int, t: float = 0.0) -> tuple[str | None, int]:
        """Returns (reject reason or None, number of frames lost); `t`: the frame's time, kept as
        `synced_at` when this frame takes the counter up afresh."""
        if self.last is None:
            self.last, self.synced_at = c, t
            return None, 0
        d = (c - self.last) & 0x0F
        if 1 <= d <= self.max_jump:
            self.last, self.candidate = c, None
            return None, d - 1
        if self.candidate is not None and ((c - self.candidate) & 0x0F) == 1:
            self.last, self.candidate, self.synced_at = c, None, t
            return None, 0
        self.candidate = c
        return ("counter_repeated" if d == 0 else "counter_sequence"), 0


RESYNC_HOLD_S = 0.030  # a node acts on no command but NOP and the safe ones this long after a resync (rule 7)


def node_acts_in_hold(name: str, sig: dict) -> bool:
    """What the gateway and the board act on within RESYNC_HOLD_S of a resync: NOP, the commands
    that only make the node safer (IGN_CMD DISARM / EXTINGUISH, ARM_CMD STOP), and target sets
    (applied only in HOLDING / TRACKING, which needs an ENABLE, and checked for jumps there)."""
    if name == "IGN_CMD":
        return int(sig["Command"]) in (IGN_NOP, IGN_DISARM, IGN_EXTINGUISH)
    if name == "ARM_CMD":
        return int(sig["Command"]) in (ARM_NOP, ARM_STOP)
    return True


class Receiver:
    """Validates and decodes the frames one node consumes.

    `accept(msg)` returns (name, signals) for a valid frame of a consumed id, else None; every
    rejection is counted in `stats.rejected[reason]` (ids of the DBC meant for other nodes are
    only counted as `ignored`). Call from one thread (the Notifier's or the node's loop).
    """

    def __init__(self, consume: set[str], max_counter_jump: int = 3, resync_hold_s: float = 0.0,
                 acts_in_hold: Callable[[str, dict], bool] | None = None) -> None:
        """`resync_hold_s` > 0 (the nodes, gateway and board: docs/protocols/can.md rule 7): for
        this long after a frame took its id's counter up afresh (first frame, re-synchronisation),
        frames of that id are checked and advance the counter but are rejected (`resync_hold`)
        unless `acts_in_hold(name, signals)` (NOP and the commands that only make the node safer).
        A stale queue flushed after a stall arrives as one burst: its first frame is rejected by
        the counter, and without the hold the rest would follow it in step and be acted on."""
        self.db = database()
        self.resync_hold_s = resync_hold_s
        self._acts_in_hold = acts_in_hold or (lambda name, sig: False)
        self._consume = {self.db.get_message_by_name(n).frame_id for n in consume}
        self._known = {m.frame_id for m in self.db.messages}
        self._checks = {fid: _CounterCheck(max_counter_jump) for fid in self._consume}
        # per consumed id: (signal, min, max, tolerance of half a step for the float scaling)
        self._ranges = {fid: [(g.name, g.minimum, g.maximum, abs(g.scale) / 2) for g in self.db.get_message_by_frame_id(fid).signals
                              if g.minimum is not None and g.maximum is not None] for fid in self._consume}
        self.stats = RxStats()
        self.last_reject: str | None = None

    def reject(self, reason: str) -> None:
        """Count a rejection (also used by set consumers for discarded halves: 'pair')."""
        self.stats.rejected[reason] += 1
        self.last_reject = reason

    def accept(self, msg: can.Message) -> tuple[str, dict] | None:
        fid = msg.arbitration_id
        if msg.is_error_frame:
            self.reject("remote_or_error")
            return None
        if msg.is_extended_id:  # 29-bit: never a frame of this protocol, whatever its number
            self.reject("extended_id")
            return None
        if msg.is_remote_frame:
            self.reject("remote_or_error" if fid in self._known else "unknown_id")
            return None
        if getattr(msg, "is_fd", False):
            self.reject("fd")
            return None
        if fid not in self._known:
            self.reject("unknown_id")
            return None
        if fid not in self._consume:
            self.stats.ignored += 1
            return None
        m = self.db.get_message_by_frame_id(fid)
        data = bytes(msg.data)
        if len(data) != m.length or msg.dlc != m.length:
            self.reject("dlc")
            return None
        protected = is_protected(m)
        if protected and data[CHECKSUM_BYTE] != frame_checksum(fid, data):
            self.reject("checksum")
            return None
        try:
            sig = m.decode(data, decode_choices=False, scaling=True)
        except Exception:  # noqa: BLE001 - any decode problem is a rejected frame
            self.reject("decode")
            return None
        if any(not lo - tol <= sig[name] <= hi + tol for name, lo, hi, tol in self._ranges[fid]):
            self.reject("range")
            return None
        if protected:
            check = self._checks[fid]
            t = msg.timestamp or time.time()  # bus receive time (python-can: time.time() based)
            reason, lost = check.check(int(sig["Counter"]), t)
            if reason:
                self.reject(reason)
                return None
            self.stats.lost += lost
            if self.resync_hold_s > 0 and t - check.synced_at < self.resync_hold_s and not self._acts_in_hold(m.name, sig):
                self.reject("resync_hold")
                return None
        self.stats.accepted += 1
        return m.name, sig


# ---- joint sets split over two frames -------------------------------------------------------
PAIR_WINDOW_S = 0.030  # a host thread can lose the GIL for a few 5 ms switch intervals between A and B


class SetPairer:
    """Joins the A and B halves of a joint set (ARM_TARGET_A/B, ARM_STATE_A/B).

    A B half is paired only with the immediately preceding frame of the pair's two ids if that
    frame is an A with the same counter and the B arrived within `window` s of it (bus receive
    timestamps). Anything else between them — another A or B (accepted or rejected), or an
    interrupting command (`interrupt()`) — discards the pending A. A B that cannot be paired
    returns None (the caller discards it and counts it: reason 'pair'); a lone A is simply never
    applied. Call from one thread.
    """

    def __init__(self, window: float = PAIR_WINDOW_S) -> None:
        self.window = window
        self._a: tuple[int, tuple, float] | None = None
        self.paired = 0
        self.discarded_b = 0
        self.dropped_a = 0  # A halves never completed

    def a(self, counter: int, values, stamp: float) -> None:
        if self._a is not None:
            self.dropped_a += 1
        self._a = (int(counter), tuple(values), float(stamp))

    def b(self, counter: int, values, stamp: float) -> tuple | None:
        """The joined set (A values + B values), or None: discard this B."""
        pa, self._a = self._a, None
        if pa is None or pa[0] != int(counter) or not (0.0 <= float(stamp) - pa[2] <= self.window):
            if pa is not None:
                self.dropped_a += 1
            self.discarded_b += 1
            return None
        self.paired += 1
        return pa[1] + tuple(values)

    def interrupt(self) -> None:
        """A frame that breaks a set (rejected half, command in between): drop the pending A."""
        if self._a is not None:
            self.dropped_a += 1
            self._a = None

    @property
    def pending(self) -> bool:
        return self._a is not None
