"""`capm-field bench`: the paper's simulation protocol (§V-A) and Table I, side by side.

Protocol: N TROIs with X_w uniform in a 3×3 m workspace, r_w ~ U[0.2, 0.3] m, MPOI
X̄_w ~ N(X_w, Σ_w) with Σ_w = r_w·I (reading configurable), five path lengths 2.75…4.75 m.
Reading of "path length" (docs/bench.md): straight start→end distance L with X_w at the midpoint
(`--span midpoint`) or at a uniform point of the middle half (`--span random`); the path
direction is uniform. One MPOI per TROI is shared by every planner and path length (common
random numbers). Success = the flame pose satisfies EPMC against the true MPOI (x_b ∈ R_m(X̄_w)).

Each trial draws from its own SeedSequence(seed, trial), so the figures depend only on --seed
and --trials, not on the number of worker processes.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import sys
import time
from dataclasses import dataclass

import numpy as np

from . import cli_args
from .config import MIN_TROI_RADIUS, TASK_FLAGS, ArmConfig, ReachabilityConfig, RobotConfig, TaskConfig, build
from .errors import UserError, check_output, write_output
from .geometry import SE2
from .keystates import TROI
from .planners import ALL_PLANNERS, PLANNERS, PlannerOptions, PlanningCore, make_planner
from .reachability import get_maps
from .robot_model import RobotModel

PATH_LENGTHS = (2.75, 3.25, 3.75, 4.25, 4.75)
PAPER_TABLE = {  # Table I of the paper: success %, Avg(c) per path length
    "a": (38, (3.29, 3.56, 4.01, 4.21, 4.52)),
    "b": (100, (4.35, 4.62, 4.89, 5.18, 5.48)),
    "c": (100, (3.82, 4.20, 4.46, 4.73, 5.09)),
}
PAPER_ETA = (0.14, 0.10, 0.10, 0.09, 0.08)
# The reading that reproduces Table I best (docs/bench.md): plain distance, γ_eff = 0.5, Σ_w a covariance.
DEFAULT_GAMMA = 0.5


@dataclass(frozen=True)
class BenchSpec:
    trials: int = 1000
    seed: int = 0
    planners: tuple[str, ...] = PLANNERS
    lengths: tuple[float, ...] = PATH_LENGTHS
    span: str = "midpoint"
    workspace: float = 3.0
    r_range: tuple[float, float] = (0.2, 0.3)


def _trial_inputs(spec: BenchSpec, task: TaskConfig, i: int):
    rng = np.random.default_rng(np.random.SeedSequence([spec.seed, i]))
    X = rng.uniform(0.0, spec.workspace, size=2)
    r = float(rng.uniform(*spec.r_range))
    mpoi = X + rng.normal(scale=task.sigma(r), size=2)
    dirs = rng.uniform(-math.pi, math.pi, size=len(spec.lengths))
    fracs = rng.uniform(0.25, 0.75, size=len(spec.lengths)) if spec.span == "random" else np.full(len(spec.lengths), 0.5)
    return TROI(float(X[0]), float(X[1]), r, id=str(i)), mpoi, dirs, fracs, int(rng.integers(2**31))


# Worker state (set once per process; fork shares the maps copy-on-write).
_CORE: PlanningCore | None = None
_OPTS: PlannerOptions | None = None


def _init(core: PlanningCore, opts: PlannerOptions) -> None:
    global _CORE, _OPTS
    _CORE, _OPTS = core, opts


def _run_trials(args: tuple[BenchSpec, list[int]]) -> list[tuple]:
    spec, idx = args
    core, opts = _CORE, _OPTS
    assert core is not None and opts is not None
    rows = []
    for i in idx:
        troi, mpoi, dirs, fracs, pseed = _trial_inputs(spec, core.task, i)
        for li, (L, th, f) in enumerate(zip(spec.lengths, dirs, fracs)):
            u = np.array([math.cos(th), math.sin(th)])
            S = np.array(troi.xy) - f * L * u
            E = S + L * u
            start, end = SE2(S[0], S[1], th), SE2(E[0], E[1], th)
            for name in spec.planners:
                planner = make_planner(name, core, opts, seed=pseed + li)
                t0 = time.perf_counter()
                plan = planner.plan(start, end, troi)
                dt = time.perf_counter() - t0
                out = planner.after_observation(plan, mpoi)
                rows.append((name, li, out.success, out.cost, dt, out.branch == "upper", plan.p_upper))
    return rows


def run_bench(core: PlanningCore, spec: BenchSpec, opts: PlannerOptions, workers: int, progress: bool = True) -> dict:
    """Run the protocol; returns the JSON-ready result dict."""
    chunks = [list(range(s, min(s + 25, spec.trials))) for s in range(0, spec.trials, 25)]
    rows: list[tuple] = []
    bar = _progress(spec.trials, progress)
    if workers > 1 and len(chunks) > 1:
        ctx = mp.get_context("fork")
        with ctx.Pool(workers, initializer=_init, initargs=(core, opts)) as pool:
            for part, ch in zip(pool.imap(_run_trials, [(spec, c) for c in chunks]), chunks):
                rows += part
                bar.update(len(ch))
    else:
        _init(core, opts)
        for ch in chunks:
            rows += _run_trials((spec, ch))
            bar.update(len(ch))
    bar.close()
    return _summarise(rows, spec)


def _progress(total: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, desc="bench trials", unit="TROI", disable=not enabled, file=sys.stderr, leave=False)


def _summarise(rows: list[tuple], spec: BenchSpec) -> dict:
    results = []
    by = {}
    for name, li, ok, cost, dt, upper, p in rows:
        by.setdefault((name, li), []).append((ok, cost, dt, upper, p))
    for name in spec.planners:
        for li, L in enumerate(spec.lengths):
            v = by.get((name, li), [])
            ok = np.array([x[0] for x in v], bool)
            cost = np.array([x[1] for x in v])
            results.append(
                {
                    "planner": name,
                    "path_length": L,
                    "success_rate": float(ok.mean()) if len(v) else 0.0,
                    "avg_cost": float(cost.mean()) if len(v) else math.nan,
                    "cost_sem": float(cost.std(ddof=1) / math.sqrt(len(cost))) if len(v) > 1 else math.nan,
                    "upper_branch_rate": float(np.mean([x[3] for x in v])) if len(v) else 0.0,
                    "mean_p_k1": float(np.mean([x[4] for x in v])) if len(v) else 0.0,
                    "trials": len(v),
                }
            )
    lat = {}
    for name in spec.planners:
        d = np.array([r[4] for r in rows if r[0] == name]) * 1e3
        if len(d):
            lat[name] = {"median": float(np.median(d)), "p99": float(np.percentile(d, 99))}
    eta = []
    if "b" in spec.planners and "c" in spec.planners:
        for li in range(len(spec.lengths)):
            b = next(r for r in results if r["planner"] == "b" and r["path_length"] == spec.lengths[li])["avg_cost"]
            c = next(r for r in results if r["planner"] == "c" and r["path_length"] == spec.lengths[li])["avg_cost"]
            eta.append((b - c) / c)
    return {"results": results, "plan_latency_ms": lat, "eta_bc": eta}


def format_table(res: dict, spec: BenchSpec) -> str:
    lines = []
    hdr = "Alg.   success   " + "  ".join(f"{L:>12.2f}" for L in spec.lengths)
    lines.append("Avg(c) at path length (m) — ours [paper]")
    lines.append(hdr)
    for name in spec.planners:
        rs = [r for r in res["results"] if r["planner"] == name]
        succ = np.mean([r["success_rate"] for r in rs]) * 100
        paper = PAPER_TABLE.get(name)
        cells = []
        for li, r in enumerate(rs):
            ref = f"[{paper[1][li]:.2f}]" if paper and spec.lengths == PATH_LENGTHS else ""
            cells.append(f"{r['avg_cost']:>5.2f} {ref:>6}")
        sref = f"[{paper[0]:>3d}]" if paper else ""
        lines.append(f"{name:<6} {succ:5.1f}% {sref:>5}  " + "  ".join(f"{c:>12}" for c in cells))
    if res["eta_bc"]:
        cells = [f"{e:>5.3f} [{p:.2f}]" if spec.lengths == PATH_LENGTHS else f"{e:>5.3f}" for e, p in zip(res["eta_bc"], PAPER_ETA)]
        lines.append(f"{'η_bc':<21}" + "  ".join(f"{c:>12}" for c in cells))
    for name, v in res["plan_latency_ms"].items():
        lines.append(f"plan latency ({name}): median {v['median']:.3f} ms, p99 {v['p99']:.3f} ms")
    return "\n".join(lines)


def rmse_vs_paper(res: dict, spec: BenchSpec) -> float:
    errs = []
    for r in res["results"]:
        if r["planner"] in PAPER_TABLE and spec.lengths == PATH_LENGTHS:
            errs.append(r["avg_cost"] - PAPER_TABLE[r["planner"]][1][spec.lengths.index(r["path_length"])])
    return float(np.sqrt(np.mean(np.square(errs)))) if errs else math.nan


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="capm-field bench", description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=cli_args.count(1, 1_000_000), default=1000, help="TROIs per path length (paper: N = 1000)")
    ap.add_argument("--seed", type=cli_args.seed, default=0)
    ap.add_argument("--planners", default="a,b,c", help="comma-separated subset of a,b,c,cstar")
    ap.add_argument("--lengths", default=",".join(str(x) for x in PATH_LENGTHS), help="path lengths (m)")
    ap.add_argument("--span", choices=("midpoint", "random"), default="midpoint", help="where X_w lies on the path")
    ap.add_argument("--gamma", type=float, default=DEFAULT_GAMMA, help="γ (the paper prints 2; 0.5 reproduces Table I)")
    ap.add_argument("--distance", choices=("euclidean", "squared"), default="euclidean", help="form of ‖ΔX‖ in d")
    ap.add_argument("--sigma", choices=("variance", "std"), default="variance", help="Σ_w = r_w·I as covariance, or σ = r_w")
    ap.add_argument("--delta", type=float, default=TaskConfig().delta, help="δ, NSV resolution threshold in (0, 1]")
    ap.add_argument("--eps-min", type=float, default=TaskConfig().eps_min, help="ε_min (m², EPMC)")
    ap.add_argument("--eps-max", type=float, default=TaskConfig().eps_max, help="ε_max (m², EPMC)")
    ap.add_argument("--radius-range", default="0.2,0.3", help="TROI radius range r_w (m): MIN,MAX")
    ap.add_argument("--urdf", type=cli_args.path, help="Z1 URDF (default: the one shipped in example-robot-data)")
    ap.add_argument("--tiebreak", choices=("first", "uniform", "nearest"), default="uniform", help="planner (a) among equal stops")
    ap.add_argument("--workers", type=cli_args.workers, default=min(2, os.cpu_count() or 1), help="processes (1-64)")
    ap.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    ap.add_argument("--readings", action="store_true", help="run every reading of the paper's ambiguities and compare")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    return ap


def _core_for(task: TaskConfig, progress: bool, urdf: str | None = None) -> PlanningCore:
    robot = RobotModel(RobotConfig(arm=ArmConfig(urdf=urdf)) if urdf else RobotConfig())
    rc = ReachabilityConfig()

    def say(msg: str) -> None:
        if progress:
            print(f"reachability maps: {msg}", file=sys.stderr)

    t0 = time.perf_counter()
    maps = get_maps(robot, task, rc, progress=say)
    if progress:
        print(f"reachability maps ready in {time.perf_counter() - t0:.2f} s (key {maps.key})", file=sys.stderr)
    return PlanningCore(robot, maps, task)


def main(argv: list[str]) -> int:
    a = _parser().parse_args(argv)
    check_output(a.json, "--json")
    if a.gamma < 0:
        raise UserError(f"--gamma must be ≥ 0, got {a.gamma}")
    planners = cli_args.names(a.planners, ALL_PLANNERS, "--planners")
    lengths = cli_args.positive_floats(a.lengths, "--lengths")
    try:
        r_range = tuple(float(x) for x in a.radius_range.split(","))
    except ValueError as e:
        raise UserError(f"--radius-range: expected MIN,MAX in metres, got {a.radius_range!r}") from e
    if len(r_range) != 2 or not MIN_TROI_RADIUS <= r_range[0] <= r_range[1] or not math.isfinite(r_range[1]):
        raise UserError(f"--radius-range: need {MIN_TROI_RADIUS} ≤ MIN ≤ MAX (finite, metres), got {a.radius_range!r}")
    spec = BenchSpec(trials=a.trials, seed=a.seed, planners=planners, lengths=lengths, span=a.span, r_range=r_range)  # type: ignore[arg-type]
    task_kw = dict(delta=a.delta, eps_min=a.eps_min, eps_max=a.eps_max)
    opts = PlannerOptions(tiebreak=a.tiebreak)
    progress = not a.quiet and sys.stderr.isatty()
    if a.readings:
        return _readings(spec, opts, a.workers, a.json, progress, task_kw, a.urdf)
    task = build(TaskConfig, "task", TASK_FLAGS, gamma=a.gamma, distance_form=a.distance, sigma_reading=a.sigma, **task_kw)
    core = _core_for(task, not a.quiet, a.urdf)
    for r in r_range:
        core.ro(r)  # a radius outside the mapped range is a user error, raised before the run
    t0 = time.perf_counter()
    res = run_bench(core, spec, opts, a.workers, progress)
    wall = time.perf_counter() - t0
    res.update(
        {
            "wall_s": wall,
            "reading": {"gamma": a.gamma, "distance": a.distance, "sigma": a.sigma, "span": a.span, "tiebreak": a.tiebreak},
            "seed": a.seed,
            "rmse_vs_paper": rmse_vs_paper(res, spec),
            "regions": {"R_m": core.rm.intervals, "R_o(r=0.25)": core.ro(0.25).intervals},
        }
    )
    print(format_table(res, spec))
    print(f"cost RMSE vs paper: {res['rmse_vs_paper']:.3f}   wall: {wall:.1f} s ({spec.trials} TROIs × {len(lengths)} lengths × {len(planners)} planners)")
    if a.json:
        write_output(a.json, json.dumps(res, indent=1), "--json")
    return 0


def _readings(spec: BenchSpec, opts: PlannerOptions, workers: int, json_path: str | None, progress: bool, task_kw: dict, urdf: str | None) -> int:
    """Every reading of the ambiguities (docs/bench.md), each with its RMSE against Table I."""
    out = []
    for distance in ("euclidean", "squared"):
        for gamma in (2.0, 0.5):
            for sigma in ("variance", "std"):
                for span in ("midpoint", "random"):
                    task = build(TaskConfig, "task", TASK_FLAGS, gamma=gamma, distance_form=distance, sigma_reading=sigma, **task_kw)
                    core = _core_for(task, False, urdf)
                    sp = BenchSpec(spec.trials, spec.seed, spec.planners, spec.lengths, span, spec.workspace, spec.r_range)
                    res = run_bench(core, sp, opts, workers, progress)
                    row = {
                        "distance": distance,
                        "gamma": gamma,
                        "sigma": sigma,
                        "span": span,
                        "rmse": rmse_vs_paper(res, sp),
                        "success_a": float(np.mean([r["success_rate"] for r in res["results"] if r["planner"] == "a"])),
                        "eta_bc": res["eta_bc"],
                        "avg_c": [r["avg_cost"] for r in res["results"] if r["planner"] == "c"],
                    }
                    out.append(row)
                    eta = " ".join(f"{e:.3f}" for e in row["eta_bc"])
                    print(f"{distance:<9} γ={gamma:<3} Σ as {sigma:<8} span {span:<8} RMSE {row['rmse']:6.3f}  a-success {row['success_a']*100:5.1f}%  η_bc {eta}")
    if json_path:
        write_output(json_path, json.dumps({"readings": out}, indent=1), "--json")
    return 0
