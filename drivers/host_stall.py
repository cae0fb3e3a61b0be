"""When this process last stalled: a link's silence measured across a host stall is the host's.

The links judge a peer by how long ago its last frame or sample arrived, on this host's clock.
When this process itself does not run for a while (the payload computer paging, thermal
throttling, a C call holding the GIL, SIGSTOP), nothing is received in that time either, and on
resuming a link's watchdog thread may run before the thread that drains the queued frames: a
0.4 s stall was taken for the igniter board's heartbeat lost and ended the mission (a timing
audit). A ticker thread notes the ends of such stalls; a watchdog counts a peer's silence from
the later of its last frame and the end of the latest stall (`silent_since`), so a stalled host
gives its peers one full timeout after it resumes. Safety does not rest on these watchdogs: the
robot side stops the body and the igniter board shuts its valve on their own timers.
"""

from __future__ import annotations

import threading
import time

TICK_S = 0.01  # ticker period
STALL_S = 0.1  # a gap in the ticks longer than this is a stall of the process (or its CPU share)
# host stalls postpone a peer's silence by at most this: a host starved again and again (each tick
# late) must still find a peer that went quiet for good
MAX_DEFER_S = 2.0


class HostClock:
    def __init__(self, tick_s: float = TICK_S, stall_s: float = STALL_S) -> None:
        self.tick_ns = int(tick_s * 1e9)
        self.stall_ns = int(stall_s * 1e9)
        self.last_tick_ns = time.monotonic_ns()
        self.resumed_ns = 0  # monotonic ns at the end of the latest stall (0: none seen)
        self.stalls = 0
        self._thread = threading.Thread(target=self._run, name="host-stall-clock", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            time.sleep(self.tick_ns / 1e9)
            now = time.monotonic_ns()
            if now - self.last_tick_ns > self.stall_ns:
                self.resumed_ns = now
                self.stalls += 1
            self.last_tick_ns = now

    def silent_since(self, last_heard_ns: int) -> int:
        """From when a peer last heard at `last_heard_ns` counts as silent: that time, or the end of
        a later host stall, or now while the ticker has not yet run since one (the caller woke
        first); never later than MAX_DEFER_S after `last_heard_ns`."""
        now = time.monotonic_ns()
        resumed = now if now - self.last_tick_ns > self.stall_ns else self.resumed_ns
        return max(last_heard_ns, min(resumed, last_heard_ns + int(MAX_DEFER_S * 1e9)))


_CLOCK: HostClock | None = None
_LOCK = threading.Lock()


def host_clock() -> HostClock:
    """The process's one HostClock (started on first use)."""
    global _CLOCK
    with _LOCK:
        if _CLOCK is None:
            _CLOCK = HostClock()
        return _CLOCK
