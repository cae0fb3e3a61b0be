"""Bus evidence for a keep-alive trip on the wire bench: did our host really leave the igniter
board without an IGNITE for longer than its timeout (this process descheduled on a loaded
machine), or did the board trip with the keep-alives on time?

A listener of its own on the bench bus records the bus times (python-can `virtual`: send times)
of the host's IGNITE frames and of the board's IGN_STATUS frames reporting the keep-alive trip.
A test that did not ask for a stall may retry a `keepalive_timeout` only when `host_silence()`
exceeds the board's timeout; a trip with the keep-alives on time still fails it."""

from __future__ import annotations

import threading

import can

from drivers.can.codec import IGN_EVENT_CODES, IGN_IGNITE, Encoder, Receiver
from drivers.can.config import CanBusConfig
from drivers.can.link import open_bus

_KA = IGN_EVENT_CODES["keepalive_timeout"]


class IgniteGaps(can.Listener):
    def __init__(self, bus_cfg: CanBusConfig) -> None:
        self._ign_id = Encoder().encode("IGN_CMD", {"Command": IGN_IGNITE}).arbitration_id
        self._rx = Receiver({"IGN_STATUS"})
        self._lock = threading.Lock()
        self.ignites: list[float] = []  # bus times of the host's IGNITE frames
        self.trips: list[float] = []  # bus times of the first IGN_STATUS of each keepalive_timeout trip
        self._tripped = False
        self.bus = open_bus(bus_cfg)
        self.notifier = can.Notifier(self.bus, [self], timeout=0.05)

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_extended_id or msg.is_remote_frame:
            return
        if msg.arbitration_id == self._ign_id and len(msg.data) == 8 and msg.data[0] == IGN_IGNITE:
            with self._lock:
                self.ignites.append(msg.timestamp)
            return
        got = self._rx.accept(msg)
        if got:
            tripped = got[1]["Event"] == _KA
            with self._lock:
                if tripped and not self._tripped:  # the Event is sticky: only its first report
                    self.trips.append(msg.timestamp)
                self._tripped = tripped

    def clear(self) -> None:
        with self._lock:
            self.ignites.clear()
            self.trips.clear()

    def host_silence(self) -> float:
        """The longest bus time (s) without an IGNITE from our host since `clear()`: between two
        IGNITEs, or from the last IGNITE to the board's report of a trip after it (a host that
        stalled past the timeout sees the trip on resuming and sends no further IGNITE)."""
        with self._lock:
            ign, trips = list(self.ignites), list(self.trips)
        gaps = [b - a for a, b in zip(ign, ign[1:])]
        for t in trips:
            before = [x for x in ign if x <= t]
            if before:
                gaps.append(t - before[-1])
        return max(gaps, default=0.0)

    def close(self) -> None:
        self.notifier.stop(timeout=1.0)
        self.bus.shutdown()
