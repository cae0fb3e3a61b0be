"""`capm-field bench-fields`: whole fields of K TROIs, per-target planners vs the field planner.

Fields: K TROIs (default 20) with X_w uniform in a square of side √(K/density), r_w ~ U[0.2, 0.3],
MPOI X̄_w ~ N(X_w, Σ_w) with the Table I bench's reading (Σ_w = r_w·I a covariance; `--sigma`),
or that prior restricted to the TROI disc (`--prior in-troi`, rejection sampling; the field
planner and cstar then plan with the restricted prior). The robot starts 1 m left of the field's
middle row and ends 1 m right of it. Planners: a, b, c, cstar walked paper-style (x_kmax the
midpoint towards the next TROI, NN + 2-opt order), `field` (field_planner.py) and `oracle`
(told every MPOI). Energy model and reading as `capm-field bench` (γ = 0.5, plain distance).
"gap closed" = (E_c − E_planner)/(E_c − E_oracle) on the energy per weed. Every field has its own
seed (SeedSequence(seed, density index, field)), so figures do not depend on --workers.
The "single" row is the paper's single-TROI protocol (capm_field.bench) with the same planners.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import sys
import time

import numpy as np

from . import bench as table_bench
from . import cli_args
from .config import TASK_FLAGS, TaskConfig, build
from .errors import UserError, check_output, write_output
from .field_planner import FieldOptions
from .field_sim import FieldRun, run_planner
from .geometry import SE2
from .keystates import TROI
from .planners import PlannerOptions, PlanningCore

PLANNERS = ("a", "b", "c", "cstar", "field", "oracle")
DENSITIES = (0.5, 1.0, 2.0, 5.0)


def make_field(seed: int, di: int, f: int, K: int, density: float, task: TaskConfig, r_range=(0.2, 0.3), prior: str = "gauss"):
    """(trois, true MPOIs, start, end) of one random field."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, di, f]))
    side = math.sqrt(K / density)
    X = rng.uniform(0.0, side, size=(K, 2))
    r = rng.uniform(*r_range, size=K)
    trois = [TROI(float(X[i, 0]), float(X[i, 1]), float(r[i]), f"w{i}") for i in range(K)]
    mpoi = {}
    for i, t in enumerate(trois):
        s = task.sigma(t.r)
        while True:
            m = X[i] + rng.normal(scale=s, size=2)
            if prior != "in-troi" or np.linalg.norm(m - X[i]) <= t.r:
                break
        mpoi[t.id] = m
    return trois, mpoi, SE2(-1.0, side / 2, 0.0), SE2(side + 1.0, side / 2, 0.0)


_CORE: PlanningCore | None = None


def _init(core: PlanningCore) -> None:
    global _CORE
    _CORE = core


def _run_field(args) -> list[tuple]:
    seed, di, f, K, density, planners, prior, fopts = args
    core = _CORE
    assert core is not None
    trois, mpoi, start, end = make_field(seed, di, f, K, density, core.task, prior=prior)
    rows = []
    for name in planners:
        run: FieldRun = run_planner(core, name, trois, mpoi, start, end, PlannerOptions(), fopts, seed=f)
        rows.append((name, di, run.energy, run.targets, run.successes, run.plan_ms, run.replan_ms, run.extra_revealed))
    return rows


def _pool_map(core: PlanningCore, jobs: list, workers: int, desc: str, progress: bool) -> list:
    from tqdm import tqdm

    out: list = []
    bar = tqdm(total=len(jobs), desc=desc, unit="field", disable=not progress, file=sys.stderr, leave=False)
    if workers > 1 and len(jobs) > 1:
        with mp.get_context("fork").Pool(workers, initializer=_init, initargs=(core,)) as pool:
            for part in pool.imap(_run_field, jobs):
                out += part
                bar.update(1)
    else:
        _init(core)
        for j in jobs:
            out += _run_field(j)
            bar.update(1)
    bar.close()
    return out


def _gap(ec: float, e: float, eo: float) -> float:
    return (ec - e) / (ec - eo) if abs(ec - eo) > 1e-12 else math.nan


def summarise(rows: list[tuple], planners: tuple[str, ...], densities: tuple[float, ...], fields: int) -> list[dict]:
    res = []
    for di, dens in enumerate(densities):
        agg = {}
        for name in planners:
            v = [r for r in rows if r[0] == name and r[1] == di]
            n = sum(r[3] for r in v)
            agg[name] = {
                "planner": name,
                "density": dens,
                "success_rate": sum(r[4] for r in v) / n if n else 0.0,
                "energy_per_weed": sum(r[2] for r in v) / n if n else math.nan,
                "fields": len(v),
                "trials": n,
                "extra_revealed_per_field": float(np.mean([r[7] for r in v])) if v else 0.0,
            }
        ec = agg.get("c", {}).get("energy_per_weed", math.nan)
        eo = agg.get("oracle", {}).get("energy_per_weed", math.nan)
        for name in planners:
            agg[name]["gap_closed"] = _gap(ec, agg[name]["energy_per_weed"], eo)
            res.append(agg[name])
    return res


def single_troi_rows(core: PlanningCore, planners: tuple[str, ...], trials: int, seed: int, workers: int, progress: bool, fopts: FieldOptions) -> list[dict]:
    """The paper's single-TROI protocol: per-target planners through capm_field.bench, field and
    oracle on the same TROIs, MPOIs, paths (one start → end per path length)."""
    per = tuple(p for p in planners if p in ("a", "b", "c", "cstar"))
    spec = table_bench.BenchSpec(trials=trials, seed=seed, planners=per)
    out: dict[str, dict] = {}
    if per:
        r = table_bench.run_bench(core, spec, PlannerOptions(), workers, progress)
        for name in per:
            rs = [x for x in r["results"] if x["planner"] == name]
            out[name] = {"energy_per_weed": float(np.mean([x["avg_cost"] for x in rs])), "success_rate": float(np.mean([x["success_rate"] for x in rs])), "trials": sum(x["trials"] for x in rs)}
    for name in (p for p in planners if p in ("field", "oracle")):
        costs, ok = [], 0
        for i in range(trials):
            troi, mpoi, dirs, fracs, _ = table_bench._trial_inputs(spec, core.task, i)
            troi = TROI(troi.x, troi.y, troi.r, "t")
            for L, th, fr in zip(spec.lengths, dirs, fracs):
                u = np.array([math.cos(th), math.sin(th)])
                S = np.array(troi.xy) - fr * L * u
                E = S + L * u
                run = run_planner(core, name, [troi], {"t": mpoi}, SE2(S[0], S[1], th), SE2(E[0], E[1], th), PlannerOptions(), fopts, seed=i)
                costs.append(run.energy)
                ok += run.successes
        out[name] = {"energy_per_weed": float(np.mean(costs)), "success_rate": ok / len(costs), "trials": len(costs)}
    ec = out.get("c", {}).get("energy_per_weed", math.nan)
    eo = out.get("oracle", {}).get("energy_per_weed", math.nan)
    return [{"planner": n, "density": "single", **v, "fields": v["trials"], "gap_closed": _gap(ec, v["energy_per_weed"], eo)} for n, v in out.items()]


def latency(core: PlanningCore, fopts: FieldOptions, seed: int, K: int = 50, density: float = 2.0, fields: int = 3) -> dict:
    """Initial plan and re-plan times of the field planner on K-TROI fields (single process)."""
    plan, replan = [], []
    for f in range(fields):
        trois, mpoi, start, end = make_field(seed, 99, f, K, density, core.task)
        run = run_planner(core, "field", trois, mpoi, start, end, PlannerOptions(), fopts, seed=f)
        plan += run.plan_ms
        replan += run.replan_ms
    return {
        "field_troi": K,
        "density": density,
        "initial_median": float(np.median(plan)),
        "initial_max": float(np.max(plan)),
        "replan_median": float(np.median(replan)),
        "replan_p99": float(np.percentile(replan, 99)),
        "replans": len(replan),
    }


def format_table(results: list[dict]) -> str:
    lines = [f"{'density':>8} {'planner':<7} {'success':>8} {'E/weed':>7} {'gap closed':>10} {'reveals/field':>13}"]
    for r in results:
        d = r["density"] if isinstance(r["density"], str) else f"{r['density']:g}/m²"
        lines.append(f"{d:>8} {r['planner']:<7} {r['success_rate'] * 100:7.1f}% {r['energy_per_weed']:7.3f} {r['gap_closed']:10.3f} {r.get('extra_revealed_per_field', 0.0):13.1f}")
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="capm-field bench-fields", description=__doc__.split("\n")[0])
    ap.add_argument("--fields", type=cli_args.count(1, 10_000), default=30, help="random fields per density")
    ap.add_argument("--troi", type=cli_args.count(1, 5_000), default=20, help="TROIs per field (K; a mission's own limit)")
    ap.add_argument("--densities", default=",".join(f"{d:g}" for d in DENSITIES), help="weeds per m², comma-separated")
    ap.add_argument("--planners", default=",".join(PLANNERS), help=f"subset of {','.join(PLANNERS)}")
    ap.add_argument("--seed", type=cli_args.seed, default=0)
    ap.add_argument("--prior", choices=("gauss", "in-troi"), default="gauss", help="MPOI ~ N(X_w, Σ_w), or restricted to the TROI disc")
    ap.add_argument("--single-trials", type=cli_args.count(0, 1_000_000), default=200, help="TROIs of the single-TROI protocol row (0: skip)")
    ap.add_argument("--gamma", type=float, default=table_bench.DEFAULT_GAMMA)
    ap.add_argument("--distance", choices=("euclidean", "squared"), default="euclidean")
    ap.add_argument("--sigma", choices=("variance", "std"), default="variance")
    ap.add_argument("--latency-fields", type=cli_args.count(0, 1_000), default=3, help="50-TROI fields timed for plan latency (0: skip)")
    ap.add_argument("--workers", type=cli_args.workers, default=min(2, os.cpu_count() or 1), help="processes (1-64)")
    ap.add_argument("--json", metavar="FILE")
    ap.add_argument("--quiet", action="store_true")
    return ap


MIN_DENSITY = 1e-3  # weeds/m²: one per 1000 m²; 20 TROIs then span ~140 m


def main(argv: list[str]) -> int:
    a = _parser().parse_args(argv)
    check_output(a.json, "--json")
    planners = cli_args.names(a.planners, PLANNERS, "--planners")
    densities = cli_args.positive_floats(a.densities, "--densities")
    if min(densities) < MIN_DENSITY:  # 1e-300 /m²: a field of 1e301 m², energies of 1e150 and nan
        raise UserError(f"--densities must be ≥ {MIN_DENSITY:g} weeds/m², got {min(densities):g}")
    task = build(TaskConfig, "task", TASK_FLAGS, gamma=a.gamma, distance_form=a.distance, sigma_reading=a.sigma)
    core = table_bench._core_for(task, not a.quiet)
    fopts = FieldOptions(in_troi=a.prior == "in-troi")
    progress = not a.quiet and sys.stderr.isatty()
    t0 = time.perf_counter()
    jobs = [(a.seed, di, f, a.troi, d, planners, a.prior, fopts) for di, d in enumerate(densities) for f in range(a.fields)]
    rows = _pool_map(core, jobs, a.workers, "fields", progress)
    results = summarise(rows, planners, densities, a.fields)
    if a.single_trials > 0:
        results += single_troi_rows(core, planners, a.single_trials, a.seed, a.workers, progress, fopts)
    lat = {}
    if "field" in planners and a.latency_fields > 0:
        lat["field"] = latency(core, fopts, a.seed, fields=a.latency_fields)
    for name in planners:
        d = [x for r in rows if r[0] == name for x in r[6]]
        if d and name != "field":
            lat[name] = {"per_target_median": float(np.median(d)), "per_target_p99": float(np.percentile(d, 99))}
    wall = time.perf_counter() - t0
    print(format_table(results))
    if "field" in lat:
        L = lat["field"]
        print(
            f"field planner latency, {L['field_troi']}-TROI fields at {L['density']:g}/m²: initial plan median {L['initial_median']:.1f} ms "
            f"(max {L['initial_max']:.1f}), re-plan median {L['replan_median']:.1f} ms, p99 {L['replan_p99']:.1f} ms ({L['replans']} re-plans; 2 shared cores, noisy)"
        )
    print(f"wall {wall:.1f} s ({a.fields} fields × {len(densities)} densities × K = {a.troi}, prior {a.prior}, seed {a.seed})")
    if a.json:
        write_output(a.json, json.dumps({"results": results, "plan_latency_ms": lat, "seed": a.seed, "prior": a.prior, "troi_per_field": a.troi,
                                         "wall_s": wall, "reading": {"gamma": a.gamma, "distance": a.distance, "sigma": a.sigma}}, indent=1), "--json")
    return 0
