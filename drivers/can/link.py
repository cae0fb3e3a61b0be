"""One CAN node on the host side: bus + Notifier + Receiver + CANopen-style heartbeats.

The adapters (`CanArm`, `CanIgniter`) each own one `CanLink`. It opens the python-can bus from
config, runs exactly one `Notifier` on it (decoded, validated frames go to
`on_frame(name, signals, stamp)` in the Notifier's thread, `stamp` being the frame's bus
receive timestamp in s; frames the receiver rejected go to `on_reject(msg)` if given),
produces the host heartbeat and consumes the peer's: no valid peer heartbeat for `timeout` s
(counted from the end of a stall of this process if later: `drivers/host_stall.py`; or a peer
not OPERATIONAL, or a send error such as bus-off) makes the link lost, which the
adapters turn into `LinkLost`. `close()` stops the heartbeat thread,
then the Notifier, then shuts the bus down (that order: see DEPENDENCY_NOTES, python-can).
"""

from __future__ import annotations

import threading
import time
from typing import Callable

import can

from drivers.host_stall import host_clock
from drivers.interfaces import DriverTimeout, LinkLost

from .codec import HEARTBEAT_BASE, NMT_OPERATIONAL, RESYNC_HOLD_S, Encoder, Receiver
from .config import CanBusConfig, HeartbeatConfig


def open_bus(cfg: CanBusConfig) -> can.BusABC:
    kw = {"interface": cfg.interface, "channel": cfg.channel}
    if cfg.bitrate is not None:
        kw["bitrate"] = cfg.bitrate
    try:
        return can.Bus(**kw)
    except (can.CanError, OSError, ValueError, ImportError) as e:
        raise LinkLost(f"cannot open CAN bus {cfg.interface}:{cfg.channel}: {e}") from e


class CanLink(can.Listener):
    def __init__(
        self,
        bus_cfg: CanBusConfig,
        hb_cfg: HeartbeatConfig,
        own_heartbeat: str,
        own_node: int,
        peer_heartbeat: str,
        consume: set[str],
        on_frame: Callable[[str, dict, float], None],
        max_counter_jump: int = 3,
        on_lost: Callable[[str], None] | None = None,
        on_reject: Callable[[can.Message], None] | None = None,
    ) -> None:
        self.hb_cfg = hb_cfg
        self.encoder = Encoder()
        self._own_hb, self._own_node = own_heartbeat, own_node
        self._peer_hb = peer_heartbeat
        self._peer_hb_id = self.encoder.db.get_message_by_name(peer_heartbeat).frame_id
        self.receiver = Receiver(set(consume) | {peer_heartbeat}, max_counter_jump)
        self._rejected_seen = 0
        self._on_frame, self._on_lost, self._on_reject = on_frame, on_lost, on_reject
        self._lock = threading.Lock()
        self._send_lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self.opened_ns = time.monotonic_ns()
        self.last_peer_hb_ns: int | None = None
        self.peer_state: int | None = None
        self.lost_reason: str | None = "no heartbeat yet"
        self.lost_detected_ns: int | None = None
        self.peer_seen = threading.Event()
        self._host = host_clock()
        self._closed = False
        self.bus = open_bus(bus_cfg)
        self.notifier = can.Notifier(self.bus, [self], timeout=0.05)  # bounds stop() time
        self._thread = threading.Thread(target=self._run, name=f"canlink-{own_heartbeat}", daemon=True)
        self._thread.start()

    # ---- rx (Notifier thread) ------------------------------------------------------------
    def on_message_received(self, msg: can.Message) -> None:
        got = self.receiver.accept(msg)
        if got is None:
            if self._on_reject is not None and self.receiver.stats.rejected_total != self._rejected_seen:
                self._on_reject(msg)
            self._rejected_seen = self.receiver.stats.rejected_total
            return
        name, sig = got
        if name == self._peer_hb:
            with self._lock:
                self.last_peer_hb_ns = time.monotonic_ns()
                self.peer_state = int(sig["NmtState"])
                if self.peer_state == NMT_OPERATIONAL:
                    self.lost_reason = None
                    self.lost_detected_ns = None
                else:
                    self._mark_lost_locked(f"peer node state {self.peer_state} (not operational)")
            self.peer_seen.set()
            self._wake.set()
            return
        # bus receive time (socketcan: kernel stamp; virtual: send time); local clock if absent
        self._on_frame(name, sig, msg.timestamp or time.time())

    def on_error(self, exc: Exception) -> None:
        # Called by the Notifier for a recv error (bus-off, interface down) or a handler bug; it
        # then keeps receiving, so pause briefly: a persistent error must not spin a core.
        self.mark_lost(f"bus error: {exc}")
        time.sleep(0.01)

    # ---- heartbeat producer + consumer -----------------------------------------------------
    def _run(self) -> None:
        period = self.hb_cfg.period
        next_hb = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_hb:
                self.send(self.encoder.heartbeat(self._own_hb, self._own_node, period))
                next_hb += period
                if next_hb < now:  # fell behind (loaded CPU): do not burst
                    next_hb = now + period
            with self._lock:
                last = self.last_peer_hb_ns
                # silence counted from the end of a host stall, if later (drivers/host_stall.py)
                deadline = (self._host.silent_since(last) / 1e9 + self.hb_cfg.timeout) if last is not None else None
                if last is not None and self.lost_reason is None and time.monotonic() >= deadline:
                    self._mark_lost_locked(f"no heartbeat from {self._peer_hb} for {self.hb_cfg.timeout:.3f} s")
            wake_at = next_hb if deadline is None or self.lost_reason is not None else min(next_hb, deadline)
            self._wake.wait(max(0.0, wake_at - time.monotonic()))
            self._wake.clear()

    def _mark_lost_locked(self, reason: str) -> None:
        first = self.lost_reason is None
        self.lost_reason = reason
        if first:
            self.lost_detected_ns = time.monotonic_ns()
            if self._on_lost is not None:
                threading.Thread(target=self._on_lost, args=(reason,), daemon=True).start()

    def mark_lost(self, reason: str) -> None:
        with self._lock:
            self._mark_lost_locked(reason)

    # ---- API ------------------------------------------------------------------------------
    @property
    def ok(self) -> bool:
        return self.lost_reason is None and not self._closed

    def check(self) -> None:
        """Raise LinkLost unless the peer heartbeat is current."""
        if self._closed:
            raise LinkLost("adapter closed")
        reason = self.lost_reason
        if reason is not None:
            raise LinkLost(reason)

    def wait_peer(self, timeout: float) -> None:
        if not self.peer_seen.wait(timeout):
            raise LinkLost(f"no heartbeat from {self._peer_hb} within {timeout:.2f} s (is the gateway on the bus?)")

    def wait_lost(self, timeout: float) -> bool:
        """Wait up to `timeout` s for the link to be declared lost; True if it was."""
        end = time.monotonic() + timeout
        while self.lost_reason is None and not self._closed and time.monotonic() < end:
            time.sleep(0.005)
        return self.lost_reason is not None

    def send(self, msg: can.Message) -> bool:
        """Send a frame; a send error marks the link lost (bus-off, closed) and returns False."""
        if self._closed:
            return False
        try:
            with self._send_lock:
                self.bus.send(msg, timeout=0.01)
            return True
        except (can.CanError, OSError, ValueError) as e:
            self.mark_lost(f"send failed: {e}")
            return False

    def close(self) -> None:
        if self._closed:
            return
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout=1.0)
        self._closed = True
        try:
            self.notifier.stop(timeout=1.0)  # before bus.shutdown(): see DEPENDENCY_NOTES
        finally:
            self.bus.shutdown()


def wait_for(cv: threading.Condition, link: "CanLink", pred: Callable[[], bool], deadline: float, what: str,
             on_poll: Callable[[], None] | None = None) -> None:
    """Wait on `cv` until `pred()` holds; DriverTimeout at `deadline` (monotonic s), LinkLost as
    soon as the link reports the peer lost (only once the peer has been seen at all).
    `on_poll`, if given, runs after every wake-up (≤ 20 ms apart), outside the lock."""
    while True:
        with cv:
            if pred():
                return
            left = deadline - time.monotonic()
            if left <= 0:
                raise DriverTimeout(f"timed out waiting for {what}")
            cv.wait(min(left, 0.02))
            if link.lost_reason is not None and link.peer_seen.is_set():
                raise LinkLost(link.lost_reason)
        if on_poll is not None:
            on_poll()


SYNC_NOPS = 3  # NOPs per start-up synchronisation round (docs/protocols/can.md, "Host start-up")
SYNC_ROUNDS = 3  # rounds before giving up (each: 3 NOPs, 2 status frames)


def sync_counter(cv: threading.Condition, link: "CanLink", command: str, status: Callable[[], tuple[int, int]],
                 deadline: float, rounds: int = SYNC_ROUNDS) -> int:
    """Host start-up procedure (docs/protocols/can.md, "Host start-up"): bring the peer's counter
    check of the command id `command` (IGN_CMD, ARM_CMD) in step with this sender, acting on nothing.

    A restarted host's counter starts anywhere; the peer rejects the first frame that does not
    follow its last accepted one and accepts the next (resync rule). One round sends SYNC_NOPS
    NOPs (Command 0, no effect on either node) with consecutive counters, then waits for two
    status frames received after the last one (the peer has processed them by the second). Under
    the receiver rules at most the first of them can be rejected, so RxRejected rising by at most
    1 over the round means the last ones were accepted: the peer is in step and the next command
    is accepted. A larger rise (a NOP rejected for another reason, or other rejected traffic on
    the bus) repeats the round. No real command is ever sent twice.

    `status()` (called with `cv` held) returns (status frames received so far, the peer's
    RxRejected in the latest one). Returns the rounds used; raises DriverTimeout if no round
    confirms within `rounds` or by `deadline`, LinkLost if the link fails.
    """
    for k in range(1, rounds + 1):
        with cv:
            _, rej0 = status()
        for _ in range(SYNC_NOPS):
            if not link.send(link.encoder.encode(command, {"Command": 0})):
                link.check()
                raise LinkLost(f"cannot send {command}")
        sent_at = time.monotonic()
        with cv:
            n_sent = status()[0]
        wait_for(cv, link, lambda: status()[0] >= n_sent + 2, deadline, f"status after the {command} counter sync")
        # the node acts on no real command within RESYNC_HOLD_S of the resync these NOPs made (rule 7)
        time.sleep(max(0.0, sent_at + RESYNC_HOLD_S - time.monotonic()))
        with cv:
            rose = (status()[1] - rej0) & 0xFF
        if rose <= 1:
            return k
    raise DriverTimeout(f"{command} counter not confirmed in step after {rounds} rounds (peer RxRejected kept rising)")


def heartbeat_id(node: int) -> int:
    return HEARTBEAT_BASE + node
