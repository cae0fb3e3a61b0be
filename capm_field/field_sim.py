"""Planner-level simulation of a whole field (no images): what the executive would do, in energy.

Per-target planners (a, b, c, cstar) walk the targets in NN + 2-opt order the way
`mission/executive.py` does: plan(here, x_kmax, TROI) with x_kmax the midpoint towards the next
TROI (the user's end pose after the last), `after_observation` with the true MPOI, walk on to
x_kmax. The field planner and the oracle use their own interface (`FieldPlanner`). An
observation reveals the MPOI of the target and of every other not-yet-known TROI whose disc
satisfies NSV (coverage + h ≥ δ, view rays clear of the body) in the same image — the image
being the actual camera pose the planner chose (a bank pose, view_bank.py). Energy is the sum of
the Outcome costs (paper energy model, reposition always a move); success = the flame stop is in
R_m(true X̄_w) (`Regions.in_R_m`, the full map with bearings).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .field_order import order_points
from .field_planner import FieldOptions, FieldPlanner, OraclePlanner, view_bank
from .geometry import SE2
from .keystates import TROI
from .planners import BayesPlanner, PlannerOptions, PlanningCore, make_planner


@dataclass
class FieldRun:
    planner: str
    energy: float
    targets: int
    successes: int
    moves: int
    plan_ms: list[float] = field(default_factory=list)  # initial plan (start + first next_plan)
    replan_ms: list[float] = field(default_factory=list)  # observed + after_observation + next_plan
    views: int = 0
    extra_revealed: int = 0
    view_failures: int = 0


def paper_x_kmax(ordered: list[TROI], i: int, end: SE2) -> SE2:
    """x_kmax as in the paper and mission/executive.py: midpoint towards the next TROI."""
    if i + 1 >= len(ordered):
        return end
    a, b = np.array(ordered[i].xy), np.array(ordered[i + 1].xy)
    m = 0.5 * (a + b)
    return SE2(float(m[0]), float(m[1]), math.atan2(b[1] - a[1], b[0] - a[0]))


def run_per_target(core: PlanningCore, name: str, trois: list[TROI], mpoi: dict[str, np.ndarray], start: SE2, end: SE2, opts: PlannerOptions, seed: int, in_troi: bool = False) -> FieldRun:
    """A per-target planner walked over the field, paper-style."""
    idx = order_points(np.array([t.xy for t in trois]), start.xy, end.xy)
    ordered = [trois[k] for k in idx]
    if name == "cstar" and in_troi:
        planner = BayesPlanner(core, opts, seed, in_troi=True)
    else:
        planner = make_planner(name, core, opts, seed)
    run = FieldRun(name, 0.0, len(trois), 0, 0)
    here = start
    for i, t in enumerate(ordered):
        x_kmax = paper_x_kmax(ordered, i, end)
        t0 = time.perf_counter()
        plan = planner.plan(here, x_kmax, t)
        run.replan_ms.append((time.perf_counter() - t0) * 1e3)
        out = planner.after_observation(plan, mpoi[t.id])
        run.energy += out.cost
        run.successes += int(out.success)
        run.moves += out.body_moves
        here = x_kmax
    return run


def run_field_planner(core: PlanningCore, name: str, trois: list[TROI], mpoi: dict[str, np.ndarray], start: SE2, end: SE2, fopts: FieldOptions, seed: int) -> FieldRun:
    """The field planner (or the oracle) over the field, with multi-TROI reveals."""
    truth = {t.id: (float(mpoi[t.id][0]), float(mpoi[t.id][1])) for t in trois}
    planner: FieldPlanner = OraclePlanner(core, fopts, seed, truth) if name == "oracle" else FieldPlanner(core, fopts, seed)
    bank = view_bank(core)
    run = FieldRun(name, 0.0, len(trois), 0, 0)
    by_id = {t.id: t for t in trois}
    t0 = time.perf_counter()
    planner.start(trois, start, end)
    plan = planner.next_plan(start, {})
    run.plan_ms.append((time.perf_counter() - t0) * 1e3)
    handled: set[str] = set()
    while plan is not None:
        tid = plan.troi.id
        dt = 0.0
        if plan.state("x_e,k2") is not None:
            run.views += 1
            also: dict[str, tuple[float, float]] = {}
            T = plan.terms.get("view_T")
            if T is None:
                run.view_failures += 1
            else:
                others = [i for i in planner.order if i != tid and i not in planner.known]
                if others:
                    seen = bank.seen_from(T, plan.x_b_k1, np.array([by_id[i].xy for i in others]), np.array([core.effective_radius(by_id[i].r) for i in others]))
                    also = {i: truth[i] for i, s in zip(others, seen) if s}
                    run.extra_revealed += len(also)
            t0 = time.perf_counter()
            planner.observed(tid, truth[tid], also)
            dt += time.perf_counter() - t0
        t0 = time.perf_counter()
        out = planner.after_observation(plan, truth[tid])
        planner.done(tid, True)
        dt += time.perf_counter() - t0
        run.energy += out.cost
        run.successes += int(out.success)
        run.moves += out.body_moves
        handled.add(tid)
        here = out.key_states[-1].body
        t0 = time.perf_counter()
        plan = planner.next_plan(here, {})
        dt += time.perf_counter() - t0
        if plan is not None:
            run.replan_ms.append(dt * 1e3)
    if len(handled) != len(trois):  # pragma: no cover - the planner must visit every target
        raise RuntimeError(f"{name}: {len(trois) - len(handled)} targets never planned")
    if not trois:
        run.energy = float(np.linalg.norm(end.xy - start.xy)) * core.task.gamma + 1.0
    return run


def run_planner(core: PlanningCore, name: str, trois: list[TROI], mpoi: dict[str, np.ndarray], start: SE2, end: SE2, opts: PlannerOptions, fopts: FieldOptions, seed: int) -> FieldRun:
    if name in ("field", "oracle"):
        return run_field_planner(core, name, trois, mpoi, start, end, fopts, seed)
    return run_per_target(core, name, trois, mpoi, start, end, opts, seed, fopts.in_troi)
