"""`capm-field run MISSION.yaml` and `capm-field validate MISSION.yaml`.

run: exit 0 when every target was handled (flamed, or skipped with a logged reason), 1 when the
mission aborted (link loss, E-stop, …), 2 for bad input (nothing started, nothing written).
Writes DIR/run.mcap and DIR/summary.json (DIR from --out or the mission's output.dir).
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import os
import re
import sys
import time
from pathlib import Path

from capm_field.cli_args import seed as cli_seed
from capm_field.errors import UserError

from .config import Mission, MissionError, load_mission


def _validate_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="capm-field validate", description="check a mission file without running it")
    ap.add_argument("mission")
    return ap


def check_hardware_files(mission: Mission, mission_path: str | Path) -> None:
    """The files a hardware run opens first: the zenoh config and what it names (TLS certificates
    and keys), resolved as the run resolves them; MissionError (exit 2) for a bad one. `validate`
    and `run` both call it, `run` before any driver opens."""
    zspec = getattr(mission.drivers, "zenoh", None)
    if zspec is None or not zspec.config_file:
        return
    from drivers.body_protocol import load_config_file
    from drivers.zenoh_body import ZenohBodyConfig

    zcfg = zspec.config_file
    try:
        load_config_file(ZenohBodyConfig.from_spec(zspec, Path(mission_path).resolve().parent).link.config_file)
    except Exception as e:  # noqa: BLE001 - zenoh's parse errors are plain exceptions
        msg = " ".join(str(e).split())
        msg = re.sub(r"\s*at /\S+\.rs:\d+\.?", "", msg)  # zenoh's messages name its Rust source file
        raise MissionError([f"{mission_path}: drivers.zenoh.config_file {zcfg}: {msg[:300] or type(e).__name__}"]) from e


def validate_main(argv: list[str]) -> int:
    a = _validate_parser().parse_args(argv)
    mission, trois = load_mission(a.mission)
    check_hardware_files(mission, a.mission)
    from capm_field.robot_model import RobotModel

    RobotModel(mission.robot)  # the URDF, its flange frame and joint count (ms; the maps are left to run)
    out = Path(mission.output.dir)
    if out.exists() and not out.is_dir():
        raise MissionError([f"{a.mission}: output.dir: {out} exists and is not a directory"])
    print(f"{a.mission}: ok — {len(trois)} TROIs, planner {mission.planner}, drivers {mission.drivers.kind}")
    for w in _link_warnings(mission):
        print(f"{a.mission}: warning: {w}", file=sys.stderr)
    return 0


def _link_warnings(mission: Mission) -> list[str]:
    """A hardware mission that would talk to the robot off this machine without TLS: allowed (a
    lab network), but docs/security.md asks for mutual TLS and the robot side refuses it unless
    started with --insecure."""
    z = getattr(mission.drivers, "zenoh", None)
    if z is None or z.config_file:
        return []
    from drivers.body_protocol import is_loopback_endpoint

    off = [e for e in list(z.connect) + list(z.listen) if not is_loopback_endpoint(e)]
    return [f"drivers.zenoh: {', '.join(off)} without a config_file: no TLS, no authentication (docs/security.md)"] if off else []


def _run_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="capm-field run", description=__doc__.split("\n")[0])
    ap.add_argument("mission", help="mission YAML file")
    ap.add_argument("--out", help="output directory (default: the mission's output.dir)")
    ap.add_argument("--seed", type=cli_seed, help="bench seed ≥ 0 (overrides drivers.seed)")
    ap.add_argument("--faults", help="bench fault schedule: 'random:SEED' or KIND@TARGET[,KIND@TARGET...]")
    ap.add_argument("--quiet", action="store_true", help="no progress line")
    ap.add_argument("--force", action="store_true", help="overwrite run.mcap/summary.json already in the output directory")
    return ap


class _Progress:
    """One status line on a terminal (target i/N, phase, energy so far); plain lines otherwise."""

    def __init__(self, enabled: bool):
        self.enabled = enabled
        self.tty = sys.stderr.isatty()
        self._last = ""

    def __call__(self, s: dict) -> None:
        if not self.enabled:
            return
        line = f"target {min(s['index'] + 1, s['total'])}/{s['total']} {s['target']:<6} {s['phase']:<20} energy {s['energy']:7.2f}"
        if self.tty:
            sys.stderr.write("\r" + line.ljust(len(self._last)))
            sys.stderr.flush()
        elif s["phase"] in ("plan", "done"):
            print(line, file=sys.stderr)
        self._last = line

    def close(self) -> None:
        if self.enabled and self.tty:
            sys.stderr.write("\n")


def _open_drivers(mission: Mission, robot, trois, seed: int | None, mission_dir: Path):
    if mission.drivers.kind == "bench":
        from sim_bench.bench_drivers import open_bench_drivers  # dynamic choice, the executive can't tell

        s = mission.drivers.seed if seed is None else seed
        return open_bench_drivers(robot, mission.task, trois, mission.start.se2(), s, mission.drivers.mpoi_in_troi, mission.drivers.transport)
    mod = importlib.import_module("drivers.hardware")
    return mod.open_hardware_drivers(mission, robot, mission_dir)


def main(argv: list[str]) -> int:
    a = _run_parser().parse_args(argv)
    mission, trois = load_mission(a.mission)
    check_hardware_files(mission, a.mission)
    faults = []
    if mission.drivers.kind == "bench":
        from sim_bench.faults import bench_faults

        spec = a.faults if a.faults is not None else mission.drivers.faults
        faults = bench_faults(spec, len(trois), mission.drivers.transport)  # before anything is written
    elif a.faults or a.seed is not None:
        raise UserError("--faults and --seed apply to bench missions only (drivers.kind: bench)")
    out = Path(a.out or mission.output.dir)
    if out.exists() and not out.is_dir():
        raise UserError(f"--out: {out} exists and is not a directory")
    if (out / "run.mcap").exists() and not a.force:
        raise UserError(f"{out / 'run.mcap'} already exists: choose another --out or pass --force (nothing was started)")

    from capm_field.config import ReachabilityConfig
    from capm_field.planners import PlanningCore, make_planner
    from capm_field.reachability import get_maps
    from capm_field.robot_model import RobotModel

    from .executive import Executive
    from .runlog import RunLog, RunLogHandler

    quiet = a.quiet
    say = (lambda m: None) if quiet else (lambda m: print(f"reachability maps: {m}", file=sys.stderr))
    try:
        robot = RobotModel(mission.robot)
        maps = get_maps(robot, mission.task, ReachabilityConfig(), progress=say)
        core = PlanningCore(robot, maps, mission.task)
        for t in trois:
            core.effective_radius(t.r)  # every TROI must be plannable before anything starts
        planner = make_planner(mission.planner, core, seed=mission.drivers.seed if mission.drivers.kind == "bench" else 0)
    except UserError:
        raise
    except Exception as e:  # noqa: BLE001 - a robot/task the schema allows but the geometry cannot use
        raise UserError(f"{a.mission}: robot/task: no plan can be made with these values ({type(e).__name__}: "
                        f"{' '.join(str(e).split())[:200]}) (nothing was started)") from e
    from drivers.interfaces import DriverError

    made = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"--out: cannot create the output directory {out}: {e.strerror or e} (nothing was started)") from e
    try:
        drivers = _open_drivers(mission, robot, trois, a.seed, Path(a.mission).resolve().parent)
    except DriverError as e:
        if made and not any(out.iterdir()):
            out.rmdir()  # leave nothing behind for a run that never started
        print(f"capm-field run: cannot open the drivers: {type(e).__name__}: {e} (nothing started)", file=sys.stderr)
        return 1
    world = drivers.extras.get("world")
    truth = world.truth if world is not None else {}
    if world is not None and not getattr(world.clock, "realtime", False):
        clock = world.clock
        wall0 = time.time_ns()

        def now_ns() -> int:
            return wall0 + clock.now_ns()
    else:
        now_ns = time.time_ns
    log = RunLog(out / "run.mcap", robot, _camera(robot), bench=world is not None, overwrite=a.force)
    progress = _Progress(not quiet)
    hook = None
    if world is not None:
        from sim_bench.faults import FaultInjector

        if faults:
            injector = FaultInjector(faults, drivers, log_event=lambda lvl, msg: log.event(now_ns(), lvl, msg))
            hook = injector.on
    # warnings and errors of the software's Python loggers go to the console and into the run log
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    to_runlog = RunLogHandler(log, now_ns)
    logging.getLogger().addHandler(to_runlog)
    try:
        ex = Executive(trois, mission.start.se2(), mission.end_pose(), drivers, core, planner, log=log, progress=progress, truth=truth, now_ns=now_ns, timeouts=mission.timeouts, hook=hook,
                       fuel_per_s=mission.igniter.fuel_per_s, fuel_reserve=mission.igniter.fuel_reserve)
        result = ex.run()
    finally:
        logging.getLogger().removeHandler(to_runlog)
        progress.close()
        try:
            drivers.close()
        finally:
            log.close()
    summary = result.to_json()
    summary["log_s"] = log.call_time_s  # time spent in RunLog calls (logging cost)
    summary.update({"mission": str(a.mission), "planner": mission.planner, "seed": a.seed if a.seed is not None else getattr(mission.drivers, "seed", None)})
    tmp = out / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=1))
    os.replace(tmp, out / "summary.json")
    flamed = sum(t.flamed for t in result.targets)
    if not quiet:
        print(
            f"{flamed}/{len(result.targets)} flamed, success rate {result.success_rate:.2f}, energy {result.total_energy:.2f}, "
            f"wall {result.wall_s:.1f} s (logging {log.call_time_s:.2f} s, {100 * log.call_time_s / max(result.wall_s, 1e-9):.1f} %) → {out}/run.mcap, {out}/summary.json"
        )
    if result.aborted:
        print(f"capm-field run: mission aborted: {result.aborted}", file=sys.stderr)
        return 1
    return 0


def _camera(robot):
    from capm_field.camera import PinholeCamera

    return PinholeCamera.from_config(robot.cfg.camera)


__all__ = ["main", "validate_main", "MissionError"]
