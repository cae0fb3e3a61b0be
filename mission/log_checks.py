"""Checks on a run log (MCAP) alone — what a reviewer or CI can verify without the robot.

Ignition invariant: the flame is never on unless the body is stationary, the nozzle satisfies
EPMC for the detected MPOI, no fault is active and the E-stop is released. A denial can only be
acted on after it is seen, so a `/igniter/state` sample with the flame on and the interlock
denied must be followed, within `reaction_ns` (the igniter board's cutoff budget, 100 ms), by a
sample with the flame off.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .runlog_read import ReadReport, iter_run

REACTION_NS = 100_000_000


@dataclass
class IgnitionCheck:
    samples: int = 0
    flame_on_samples: int = 0
    violations: list[str] = field(default_factory=list)
    complete: bool = False
    error: str | None = None

    @property
    def ok(self) -> bool:
        return not self.violations


def check_ignition_invariant(path: str | Path, reaction_ns: int = REACTION_NS) -> IgnitionCheck:
    rep = ReadReport()
    out = IgnitionCheck()
    states = [(m.log_time, m.data) for m in iter_run(path, topics={"/igniter/state"}, report=rep)]
    out.complete, out.error = rep.complete, rep.error
    out.samples = len(states)
    for i, (t, s) in enumerate(states):
        if not s.flame_on:
            continue
        out.flame_on_samples += 1
        safe = s.interlock_ok and s.body_stationary and s.epmc_ok and not s.estop and not s.fault
        if safe:
            continue
        nxt = next(((t2, s2) for t2, s2 in states[i + 1 :] if not s2.flame_on), None)
        if nxt is None or nxt[0] - t > reaction_ns:
            why = ",".join(s.interlock_reasons) or "unsafe"
            out.violations.append(f"t={t}: flame on while denied ({why}); off {'never' if nxt is None else f'after {(nxt[0] - t) / 1e6:.0f} ms'}")
    return out
