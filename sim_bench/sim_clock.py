"""Simulated clock for the in-process drivers: time advances only when a driver steps it.

Deterministic and as fast as the CPU allows (Monte Carlo); `real_time_factor` makes `sleep`
also wait on the wall clock (1.0 = real time) when a run should be watched.
"""

from __future__ import annotations

import time


class SimClock:
    def __init__(self, start_ns: int = 0, real_time_factor: float | None = None) -> None:
        self._ns = int(start_ns)
        self.real_time_factor = real_time_factor

    def now_ns(self) -> int:
        return self._ns

    def now(self) -> float:
        return self._ns / 1e9

    def sleep(self, dt: float) -> None:
        if dt <= 0.0:
            return
        self._ns += int(round(dt * 1e9))
        if self.real_time_factor:
            time.sleep(dt / self.real_time_factor)
