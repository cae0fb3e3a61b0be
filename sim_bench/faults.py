"""Fault schedule for the bench: which fault, at which target and phase, injected through the
simulated drivers' own fault hooks (docs/faults.md lists every class and the documented response).

A schedule is a list of `Fault(kind, target, phase, params)`: `target` is the index in the
executive's visiting order, `phase` the executive phase that triggers it ("walk", "observe",
"reposition", "flame", "stow"); each fires once. `parse_faults` reads the mission's list, a CLI
spec `KIND@TARGET[:PHASE][,…]`, or `random:SEED` (1–3 random faults).

The executive calls `on(target, phase, elapsed_s)` at every phase change and on every igniter
keep-alive while flaming; the injector returns directives for faults that live in the executive's
own pipeline (an IK failure of its solvers, a detector miss).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from capm_field.cli_args import MAX_SEED
from capm_field.errors import UserError, shown

# kind → (default phase, what is injected)
FAULT_KINDS: dict[str, str] = {
    "estop": "walk",  # E-stop pressed during a walk (released after params.release_s, default never)
    "estop_flame": "flame",  # E-stop pressed while the flame is on
    "motion_failure": "walk",  # the body aborts the move (blocked)
    "slip": "walk",  # the body arrives offset (params dx, dy)
    "slip_flame": "flame",  # the body is pushed while flaming
    "ik_failure": "observe",  # the arm's IK finds no solution (next solve)
    "arm_fault": "observe",  # latched arm fault on the next arm move
    "ignition_failure": "flame",  # the igniter fails to light (every trial until cleared)
    "flame_out": "flame",  # the flame goes out mid-hold (params after_s, default 1.0)
    "fuel_empty": "flame",  # the tank runs dry while flaming
    "fuel_low": "walk",  # the tank holds only params.level (default 0.005) as a target begins
    "camera_drop": "observe",  # the next params.frames (default 1) frames are dropped (capture times out)
    "black_frame": "observe",  # the next params.frames (default 1) frames are black
    "detector_miss": "observe",  # the detector finds nothing in the next frame
    "body_link_loss": "walk",  # body link lost (LinkLost)
    "arm_link_loss": "observe",  # arm link lost / CAN bus-off (LinkLost)
    "igniter_link_loss": "flame",  # igniter link lost while flaming (LinkLost)
    "igniter_stall": "flame",  # the host stalls params.stall_s (default 0.15 s) mid-hold: no keep-alives, the board trips
    "body_freeze": "walk",  # the body stops answering (timeouts)
}


# Parameters each kind reads (`at_s`: every kind): name → (type, lower, upper). Checked when the
# schedule is parsed: a typo or a NaN would otherwise be ignored, or injected (a NaN slip) mid-run.
_SECONDS = (float, 0.0, 3600.0)
_OFFSET = (float, -5.0, 5.0)
FAULT_PARAMS: dict[str, dict[str, tuple]] = {
    "estop": {"release_s": _SECONDS},
    "estop_flame": {"release_s": _SECONDS},
    "motion_failure": {"after_s": _SECONDS},
    "slip": {"dx": _OFFSET, "dy": _OFFSET},
    "slip_flame": {"dx": _OFFSET, "dy": _OFFSET},
    "arm_fault": {"code": (str, None, None), "persist": (bool, None, None)},
    "ignition_failure": {"persist": (bool, None, None)},
    "flame_out": {"after_s": _SECONDS},
    "fuel_low": {"level": (float, 0.0, 1.0)},
    "igniter_stall": {"stall_s": (float, 0.0, 60.0)},
    "camera_drop": {"frames": (int, 1, 1000)},
    "black_frame": {"frames": (int, 1, 1000)},
}


def _check_params(f: "Fault") -> None:
    allowed = {"at_s": _SECONDS, **FAULT_PARAMS.get(f.kind, {})}
    for name, v in f.params.items():
        if name not in allowed:
            raise UserError(f"fault {f.kind}: unknown parameter {name!r}; it takes {', '.join(sorted(allowed))}")
        typ, lo, hi = allowed[name]
        if typ is float:
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and lo <= v <= hi
            need = f"a number in [{lo:g}, {hi:g}]"
        elif typ is int:
            ok = isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi
            need = f"a whole number in [{lo}, {hi}]"
        else:
            ok, need = isinstance(v, typ), f"a {typ.__name__}"
        if not ok:
            raise UserError(f"fault {f.kind}: parameter {name} must be {need} (got {v!r:.40})")


@dataclass
class Fault:
    kind: str
    target: int = 0
    phase: str | None = None
    params: dict[str, Any] = field(default_factory=dict)
    fired: bool = False

    @property
    def trigger_phase(self) -> str:
        return self.phase or FAULT_KINDS[self.kind]


def parse_faults(spec: Any, n_targets: int) -> list[Fault]:
    """Faults from a mission list (dicts with kind/target/phase/params), 'random:SEED' or 'K@T[:P],…'."""
    if not spec:
        return []
    if isinstance(spec, str):
        m = re.fullmatch(r"random:(\d+)", spec.strip())
        if m:
            if len(m.group(1)) > 19 or int(m.group(1)) > MAX_SEED:
                raise UserError(f"--faults: random seed must be ≤ {MAX_SEED} (got {len(m.group(1))} digits)")
            return random_faults(int(m.group(1)), n_targets)
        out = []
        for part in spec.split(","):
            mm = re.fullmatch(r"\s*([a-z_]+)(?:@(\d{1,9}))?(?::([a-z]+))?\s*", part)  # (int() of 4300+ digits raises)
            if not mm:
                raise UserError(f"--faults: cannot parse {shown(part)}; expected KIND@TARGET[:PHASE] or random:SEED")
            out.append(Fault(mm.group(1), int(mm.group(2) or 0), mm.group(3)))
        spec = out
    faults = []
    for f in spec:
        if isinstance(f, Fault):
            faults.append(f)
            continue
        d = f if isinstance(f, dict) else f.model_dump()
        params = dict(d.get("params") or {})
        if d.get("at_s") is not None:  # a mission's `at_s` is the params' (it was once read nowhere)
            params.setdefault("at_s", d["at_s"])
        faults.append(Fault(d["kind"], int(d.get("target") or 0), d.get("phase"), params))
    for f in faults:
        if f.kind not in FAULT_KINDS:
            raise UserError(f"fault kind {f.kind!r} unknown; choose from {', '.join(FAULT_KINDS)}")
        if f.phase is not None and f.phase not in ("walk", "observe", "reposition", "flame", "stow"):
            raise UserError(f"fault phase {f.phase!r} unknown; choose from walk, observe, reposition, flame, stow")
        if not 0 <= f.target < max(n_targets, 1):
            raise UserError(f"fault {f.kind}: target index {f.target} outside 0..{n_targets - 1}")
        _check_params(f)
    return faults


def bench_faults(spec: Any, n_targets: int, transport: str) -> list[Fault]:
    """`parse_faults`, and the rule that fault schedules run on the in-process bench only."""
    faults = parse_faults(spec, n_targets)
    if faults and transport != "inprocess":
        raise UserError("fault schedules run on the in-process bench (transport: inprocess); "
                        "wire-level faults are exercised by the driver tests")
    return faults


def random_faults(seed: int, n_targets: int, max_faults: int = 3) -> list[Fault]:
    rng = np.random.default_rng(seed)
    kinds = sorted(FAULT_KINDS)
    out = []
    for _ in range(int(rng.integers(1, max_faults + 1))):
        kind = str(rng.choice(kinds))
        params: dict[str, Any] = {}
        if kind in ("slip", "slip_flame"):
            params = {"dx": float(rng.uniform(-0.1, 0.1)), "dy": float(rng.uniform(-0.1, 0.1))}
        if kind == "flame_out":
            params = {"after_s": float(rng.uniform(0.2, 2.5))}
        if kind == "estop":
            params = {"release_s": float(rng.uniform(0.5, 5.0))} if rng.random() < 0.5 else {}
        out.append(Fault(kind, int(rng.integers(0, max(n_targets, 1))), None, params))
    return out


class FaultInjector:
    """Fires scheduled faults into the bench DriverSet through the simulated drivers' hooks."""

    def __init__(self, faults: list[Fault], drivers, log_event=None):
        self.faults = faults
        self.d = drivers
        self.log_event = log_event or (lambda *_a, **_k: None)
        self.fired: list[tuple[str, int, str]] = []
        self._release_at: float | None = None
        self._last_elapsed = 0.0

    def on(self, target: int, phase: str, elapsed_s: float = 0.0) -> set[str]:
        """Called by the executive; returns directives for the executive's own pipeline."""
        directives: set[str] = set()
        clock = self.d.extras["world"].clock
        if self._release_at is not None and clock.now() >= self._release_at:
            self.d.body.sim.release_estop()
            self._release_at = None
            self.log_event("info", "fault: E-stop released")
        new_trial = phase == "flame" and elapsed_s < self._last_elapsed
        self._last_elapsed = elapsed_s if phase == "flame" else 0.0
        for f in self.faults:
            # A failed ignition spoils one trial (the next one lights) unless it is meant to persist.
            if f.fired and f.kind == "ignition_failure" and not f.params.get("persist") and new_trial:
                self.d.igniter.hooks.fail_to_light = False
        for f in self.faults:
            if f.fired or f.target != target or f.trigger_phase != phase:
                continue
            at_s = float(f.params.get("at_s", 0.0 if f.kind in ("ignition_failure", "ik_failure") else 0.5))
            if phase == "flame" and elapsed_s < at_s:
                continue  # mid-hold faults strike once the flame has been on a while
            f.fired = True
            self.fired.append((f.kind, target, phase))
            self.log_event("warning", f"fault injected: {f.kind} at target {target} ({phase})")
            directives |= self._fire(f, clock)
        return directives

    def _fire(self, f: Fault, clock) -> set[str]:
        d, k, p = self.d, f.kind, f.params
        if k in ("estop", "estop_flame"):
            d.body.sim.press_estop(reason="fault_injection")
            if "release_s" in p:
                self._release_at = clock.now() + float(p["release_s"])
        elif k == "motion_failure":
            d.body.sim.inject_motion_failure(after_s=float(p.get("after_s", 0.2)))
        elif k in ("slip", "slip_flame"):
            d.body.sim.inject_slip(float(p.get("dx", 0.06)), float(p.get("dy", 0.04)))
            if k == "slip_flame":  # a push while standing: the body is displaced now
                d.body.sim.displace(float(p.get("dx", 0.06)), float(p.get("dy", 0.04)))
        elif k == "ik_failure":
            d.arm.hooks.fail_ik = True
            return {"ik_fail"}
        elif k == "arm_fault":
            d.arm.plant.set_fault(str(p.get("code", "overcurrent")), bool(p.get("persist", False)))
        elif k == "ignition_failure":
            d.igniter.hooks.fail_to_light = True
        elif k == "flame_out":
            d.igniter.hooks.flame_out = True
        elif k == "fuel_empty":
            d.igniter.board.fuel = 1e-6
        elif k == "fuel_low":
            d.igniter.board.fuel = float(p.get("level", 0.005))
        elif k == "camera_drop":
            d.camera.inject_drop(int(p.get("frames", 1)))
        elif k == "black_frame":
            d.camera.inject_black(int(p.get("frames", 1)))
        elif k == "detector_miss":
            return {"detector_miss"}
        elif k == "body_link_loss":
            d.body.link_lost = True
        elif k == "arm_link_loss":
            d.arm.hooks.link_lost = True
        elif k == "igniter_link_loss":
            d.igniter.hooks.link_lost = True
        elif k == "igniter_stall":
            clock.advance(float(p.get("stall_s", 0.15)))  # the host is descheduled: time passes, no keep-alive
        elif k == "body_freeze":
            d.body.sim.freeze(True)
        return set()
