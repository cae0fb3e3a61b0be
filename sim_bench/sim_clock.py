"""The bench's clock, shared by every simulated driver.

Virtual (default): time advances only when a driver sleeps/advances — deterministic and as fast
as the CPU allows (Monte Carlo, in-process missions). `real_time_factor` makes `sleep` also wait
on the wall clock (1.0 = real time) when a run should be watched. `realtime=True` follows
`time.monotonic_ns()` (wire-level bench: robot sides with their own loops, other processes).
"""

from __future__ import annotations

import time


class SimClock:
    def __init__(self, start_ns: int = 0, real_time_factor: float | None = None, realtime: bool = False) -> None:
        self._ns = int(start_ns)
        self.real_time_factor = real_time_factor
        self.realtime = realtime
        self._offset = time.monotonic_ns() - int(start_ns)

    def now_ns(self) -> int:
        return time.monotonic_ns() - self._offset if self.realtime else self._ns

    def now(self) -> float:
        return self.now_ns() / 1e9

    def sleep(self, dt: float) -> None:
        """Let `dt` s pass: a jump in virtual time, a real sleep in real time."""
        if dt <= 0.0:
            return
        if self.realtime:
            time.sleep(dt)
            return
        self._ns += int(round(dt * 1e9))
        if self.real_time_factor:
            time.sleep(dt / self.real_time_factor)

    advance = sleep  # the body model's name for it
