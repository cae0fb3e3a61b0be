"""Run N random fault schedules over a two-target bench mission and check the ignition invariant
from each run's MCAP log alone (mission/log_checks.py). Prints violations, outcomes, runtime.

    .venv/bin/python bench/fault_schedules.py --runs 1000 --workers 2 [--seed 0]
"""

from __future__ import annotations

import argparse
import collections
import multiprocessing as mp
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _one(args: tuple[int, str]) -> dict:
    seed, tmp = args
    import numpy as np

    from capm_field.camera import PinholeCamera
    from capm_field.config import ReachabilityConfig, TaskConfig
    from capm_field.geometry import SE2
    from capm_field.keystates import TROI
    from capm_field.planners import PlanningCore, make_planner
    from capm_field.reachability import get_maps
    from capm_field.robot_model import RobotModel
    from mission.executive import Executive
    from mission.log_checks import check_ignition_invariant
    from mission.runlog import RunLog
    from sim_bench.bench_drivers import open_bench_drivers
    from sim_bench.faults import FaultInjector, random_faults

    global _CORE
    if "_CORE" not in globals():
        robot = RobotModel()
        task = TaskConfig()
        _CORE = PlanningCore(robot, get_maps(robot, task, ReachabilityConfig()), task)
    core = _CORE
    rng = np.random.default_rng(seed)
    trois = [TROI(float(rng.uniform(0.8, 1.2)), float(rng.uniform(0.1, 0.5)), 0.22, "A"), TROI(float(rng.uniform(1.6, 2.0)), float(rng.uniform(0.7, 1.1)), 0.25, "B")]
    start, end = SE2(0.0, 0.0, 0.0), SE2(2.5, 1.5, 0.0)
    faults = random_faults(seed, len(trois))
    d = open_bench_drivers(core.robot, core.task, trois, start, seed)
    world = d.extras["world"]
    path = Path(tmp) / f"run-{seed}.mcap"
    log = RunLog(path, core.robot, PinholeCamera.from_config(core.robot.cfg.camera), bench=True)
    inj = FaultInjector(faults, d)
    ex = Executive(trois, start, end, d, core, make_planner("c", core), log=log, truth=world.truth, now_ns=lambda: 10**18 + world.clock.now_ns(), hook=inj.on)
    try:
        res = ex.run()
        flame_left_on = d.igniter.board.flame_on or d.igniter.board.armed
    finally:
        d.close()
        log.close()
    chk = check_ignition_invariant(path)
    path.unlink()
    return {
        "seed": seed,
        "faults": [f.kind for f in faults],
        "violations": chk.violations,
        "complete": chk.complete,
        "aborted": bool(res.aborted),
        "flamed": sum(t.flamed for t in res.targets),
        "unexplained": sum(1 for t in res.targets if not t.flamed and not t.reason),
        "flame_left_on": flame_left_on,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    from tqdm import tqdm

    t0 = time.perf_counter()
    out = []
    with tempfile.TemporaryDirectory() as tmp, mp.get_context("fork").Pool(a.workers) as pool:
        for r in tqdm(pool.imap_unordered(_one, [(a.seed + i, tmp) for i in range(a.runs)]), total=a.runs, file=sys.stderr):
            out.append(r)
    wall = time.perf_counter() - t0
    viol = [r for r in out if r["violations"] or not r["complete"] or r["flame_left_on"] or r["unexplained"]]
    kinds = collections.Counter(k for r in out for k in r["faults"])
    print(f"{len(out)} random fault schedules, {sum(len(r['faults']) for r in out)} faults ({len(kinds)} classes), wall {wall:.0f} s")
    print(f"ignition-invariant violations: {sum(len(r['violations']) for r in out)}; incomplete logs: {sum(not r['complete'] for r in out)}; "
          f"flame/armed left on: {sum(r['flame_left_on'] for r in out)}; targets dropped without a reason: {sum(r['unexplained'] for r in out)}")
    print(f"aborted missions: {sum(r['aborted'] for r in out)}; targets flamed: {sum(r['flamed'] for r in out)}/{2 * len(out)}")
    for r in viol[:10]:
        print("  problem:", r)
    return 1 if viol else 0


if __name__ == "__main__":
    sys.exit(main())
