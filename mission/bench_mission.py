"""`capm-field bench-mission MISSION.yaml [--summary RUN/summary.json]`: the planner bench on a
mission's own geometry, to check a run against it.

The TROIs are taken in the executive's order, each with the executive's x_k0 (the previous
x_kmax, or the start) and x_kmax; the MPOI is drawn `--trials` times from the same distribution as
the bench world (N(X_w, Σ_w), restricted to the TROI unless the mission says otherwise). Prints,
per target and overall, the planner's mean energy and success rate with their Monte Carlo
standard errors and, with --summary, the run's figures and their difference in standard errors.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from capm_field.cli_args import count
from capm_field.cli_args import path as cli_path
from capm_field.cli_args import seed as cli_seed
from capm_field.config import ReachabilityConfig
from capm_field.errors import UserError, check_output, finite_real, not_a_file, shown, write_output
from capm_field.keystates import TROI
from capm_field.planners import PlanningCore, make_planner
from capm_field.reachability import get_maps
from capm_field.robot_model import RobotModel

from .config import Mission, load_mission
from .ordering import order_trois, x_kmax


def _number(v: Any, where: str, lo: float = 0.0, hi: float = math.inf) -> float:
    """A finite JSON number in [lo, hi] (not a bool, not a string), else UserError naming `where`."""
    if v is None:
        raise UserError(f"{where} is missing")
    if not finite_real(v) or not lo <= v <= hi:
        raise UserError(f"{where} must be a finite number in [{lo:g}, {hi:g}], got {shown(v)}")
    return float(v)


def disc_mass(sigma: float, r: float) -> float:
    """P(‖d‖ ≤ r) for d ~ N(0, σ²I): the Rayleigh CDF 1 − exp(−r²/2σ²)."""
    return -math.expm1(-r**2 / (2 * sigma**2))


def draw_in_disc(rng: np.random.Generator, sigma: float, r: float) -> np.ndarray:
    """An offset from N(0, σ²I) conditioned on ‖d‖ ≤ r, exactly: the radius from the Rayleigh
    CDF inverted on [0, r], the direction uniform."""
    p_in = disc_mass(sigma, r)
    rho = min(sigma * math.sqrt(-2.0 * math.log1p(-rng.uniform() * p_in)), r)
    ang = rng.uniform(0, 2 * math.pi)
    return np.array([rho * math.cos(ang), rho * math.sin(ang)])


SAME_TROI_M = 1e-6  # a summary's TROI (x, y, r) within this of the mission's is the same target (JSON keeps floats exact)


def _read_summary(p: Path, mission: Mission, mission_path: str, trois: list[TROI]) -> tuple[dict, dict[str, float]]:
    """A run's summary.json (the fields used here, checked before the bench runs: a missing or
    mistyped one crashed after it) and the energy of each target it flamed, by id. Its targets must
    be this mission's: the same ids, and where the summary records a target's TROI, the same disc
    (ids are generated T00, T01, … for a mission that names none, so any two such missions of as
    many targets share them)."""
    ids = [t.id for t in trois]
    if not p.is_file():
        raise UserError(f"--summary: {not_a_file(p, 'summary')}: {p}")
    try:
        s = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as e:
        raise UserError(f"--summary: {p} is not a capm-field run's summary.json ({type(e).__name__}: {e})") from e
    except RecursionError:
        raise UserError(f"--summary: {p} is not a capm-field run's summary.json (JSON nested too deeply)") from None
    bad = f"--summary: {p} is not a capm-field run's summary.json"
    if not isinstance(s, dict) or not isinstance(s.get("targets"), list):
        raise UserError(f"{bad} (no list of targets)")
    s["success_rate"] = _number(s.get("success_rate"), f"--summary: {p}: success_rate", 0.0, 1.0)
    energies: dict[str, float] = {}
    for i, t in enumerate(s["targets"]):
        if not isinstance(t, dict) or not isinstance(t.get("id"), str) or not isinstance(t.get("flamed"), bool):
            raise UserError(f"{bad} (targets[{i}] is not a target with an id and flamed: {shown(t)})")
        if t["flamed"]:
            energies[t["id"]] = _number(t.get("energy"), f"--summary: {p}: targets[{i}] ({t['id']}) energy")
    # a summary of another mission matches no target by id: say so rather than "flamed no target"
    theirs = [t["id"] for t in s["targets"]]
    if sorted(theirs) != sorted(ids):
        who = shown(s.get("name", "?")) + (f" ({shown(s['mission'])})" if isinstance(s.get("mission"), str) else "")
        extra, missing = sorted(set(theirs) - set(ids)), sorted(set(ids) - set(theirs))
        eg = ", ".join(x for x in (f"{shown(extra[0])} is not in this mission" if extra else "",
                                   f"{shown(missing[0])} is not in the summary" if missing else "",
                                   "an id is listed twice" if len(set(theirs)) != len(theirs) else "") if x)
        raise UserError(f"--summary: {p} is from another mission: its {len(theirs)} target(s), of mission {who}, are not "
                        f"the {len(ids)} of this mission {shown(mission.name)} ({mission_path}): {eg}")
    mine = {t.id: (t.x, t.y, t.r) for t in trois}
    for i, t in enumerate(s["targets"]):
        if "troi" not in t:  # (a summary that does not record it: the ids alone)
            continue
        disc = t["troi"]
        if not (isinstance(disc, list) and len(disc) == 3 and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                                  and math.isfinite(v) for v in disc)):
            raise UserError(f"{bad} (targets[{i}] ({shown(t['id'])}) troi is not [x, y, r]: {shown(disc)})")
        if max(abs(a - b) for a, b in zip(disc, mine[t["id"]])) > SAME_TROI_M:
            x, y, r = mine[t["id"]]
            raise UserError(f"--summary: {p} is from another field: its target {shown(t['id'])} is the TROI at "
                            f"({disc[0]:g}, {disc[1]:g}) r {disc[2]:g} m, in this mission {shown(mission.name)} ({mission_path}) "
                            f"at ({x:g}, {y:g}) r {r:g} m")
    if s.get("name") not in (None, mission.name):  # same targets: a renamed copy of the mission, compared
        print(f"capm-field bench-mission: note: --summary is of mission {shown(s['name'])}, this is {shown(mission.name)} "
              "(same target ids)", file=sys.stderr)
    return s, energies


def main(argv: list[str]) -> int:
    # the docstring's first paragraph, one sentence (its first line alone stops mid-sentence)
    ap = argparse.ArgumentParser(prog="capm-field bench-mission", description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("mission")
    ap.add_argument("--trials", type=count(2, 1_000_000), default=2000, help="MPOI draws per target")
    ap.add_argument("--seed", type=cli_seed, default=0)
    ap.add_argument("--summary", type=cli_path, help="a run's summary.json to compare against")
    ap.add_argument("--json", metavar="FILE")
    a = ap.parse_args(argv)
    check_output(a.json, "--json", inputs=[a.mission] + ([a.summary] if a.summary else []))
    mission, trois = load_mission(a.mission)
    if mission.planner == "field":  # it plans across targets: no per-target plan to draw MPOIs against
        raise UserError(f"{a.mission}: planner 'field' plans across targets; bench-mission compares the per-target "
                        "planners (a, b, c, cstar): use `capm-field bench-fields` for the field planner")
    s, flamed = _read_summary(Path(a.summary), mission, a.mission, trois) if a.summary else (None, {})
    robot = RobotModel(mission.robot)
    core = PlanningCore(robot, get_maps(robot, mission.task, ReachabilityConfig()), mission.task)
    ordered = order_trois(trois, mission.start.se2().xy, mission.end_pose().xy)
    in_troi = getattr(mission.drivers, "mpoi_in_troi", True)
    rng = np.random.default_rng(a.seed)
    rows = []
    here = mission.start.se2()
    for i, t in enumerate(ordered):
        end = x_kmax(ordered, i, mission.end_pose())
        planner = make_planner(mission.planner, core, seed=a.seed + i)
        plan = planner.plan(here, end, t)
        sigma = mission.task.sigma(t.r)  # not `s`: that is the run's summary, used below
        costs, oks = [], []
        # P(a draw lands in the TROI disc): with σ ≫ r_w rejection needs ~1/p draws per sample (hours
        # for r_w of 0.1 mm); then the truncated Rayleigh radius is drawn exactly instead
        p_in = disc_mass(sigma, t.r) if in_troi else 1.0
        while len(costs) < a.trials:
            if p_in < 0.05:
                d = draw_in_disc(rng, sigma, t.r)
            else:
                d = rng.normal(scale=sigma, size=2)
                if in_troi and math.hypot(*d) > t.r:
                    continue
            out = planner.after_observation(plan, np.array(t.xy) + d)
            costs.append(out.cost)
            oks.append(out.success)
        costs_a = np.array(costs)
        rows.append({"id": t.id, "energy": float(costs_a.mean()), "energy_sd": float(costs_a.std(ddof=1)), "success_rate": float(np.mean(oks))})
        here = end
    n = len(rows)
    mean_e = float(np.mean([r["energy"] for r in rows]))
    # Standard error of a single run's mean energy per weed (one MPOI draw per target).
    se_run = float(math.sqrt(sum(r["energy_sd"] ** 2 for r in rows)) / n)
    succ = float(np.mean([r["success_rate"] for r in rows]))
    print(f"planner {mission.planner}: {n} targets, {a.trials} MPOI draws each")
    for r in rows:
        print(f"  {r['id']:<8} E[c] {r['energy']:6.3f} (sd {r['energy_sd']:.3f})  success {r['success_rate'] * 100:5.1f}%")
    print(f"bench: energy per weed {mean_e:.3f} (a single run's mean has s.e. {se_run:.3f}), success {succ * 100:.1f}%")
    result = {"planner": mission.planner, "targets": rows, "energy_per_weed": mean_e, "run_mean_se": se_run, "success_rate": succ}
    if a.summary:
        same = [r for r in rows if r["id"] in flamed]  # compare like with like: the targets the run flamed
        if not same:
            raise UserError("--summary: the run flamed no target; nothing to compare")
        bench_e = float(np.mean([r["energy"] for r in same]))
        se = float(math.sqrt(sum(r["energy_sd"] ** 2 for r in same)) / len(same))
        run_e = float(np.mean([flamed[r["id"]] for r in same]))
        z = (run_e - bench_e) / se if se > 1e-9 else math.nan
        print(
            f"run:   energy per flamed weed {run_e:.3f} vs bench {bench_e:.3f} on the same {len(same)} targets "
            f"(difference {run_e - bench_e:+.3f}, s.e. {se:.3f}), success {s['success_rate'] * 100:.1f}% "
            f"({len(flamed)}/{len(s['targets'])} flamed)"
        )
        result.update({"run_energy_per_weed": run_e, "z": z, "run_success_rate": s["success_rate"]})
    if a.json:
        write_output(a.json, json.dumps(result, indent=1), "--json")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main(sys.argv[1:]))
