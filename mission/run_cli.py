"""`capm-field run MISSION.yaml` and `capm-field validate MISSION.yaml`.

run: exit 0 when every target was handled (flamed, or skipped with a logged reason), 1 when the
mission aborted (link loss, E-stop, …), 2 for bad input (nothing started, nothing written),
130 / 143 / 129 when interrupted by Ctrl-C / SIGTERM / SIGHUP (flame off, summary marked interrupted).
Writes DIR/run.mcap and DIR/summary.json (DIR from --out or the mission's output.dir).
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import os
import signal
import sys
import threading
import time
from pathlib import Path

from capm_field.cli_args import seed as cli_seed
from capm_field.errors import UserError

from .config import Mission, MissionError, fuel_warnings, load_mission, overlap_warnings, robot_model
from .interrupts import STOP_SIGNALS, HeldSignals

OUTPUTS = ("run.mcap", "summary.json")


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
    from drivers.body_protocol import load_config_file, zenoh_error_text
    from drivers.zenoh_body import ZenohBodyConfig

    zcfg = zspec.config_file
    try:
        load_config_file(ZenohBodyConfig.from_spec(zspec, Path(mission_path).resolve().parent).link.config_file)
    except Exception as e:  # noqa: BLE001 - zenoh's parse errors are plain exceptions
        msg = zenoh_error_text(e)  # without zenoh's Rust source path and debug structs
        raise MissionError([f"{mission.where('drivers', 'zenoh', 'config_file')}: drivers.zenoh.config_file {zcfg}: {msg[:300]}"]) from e


def validate_main(argv: list[str]) -> int:
    a = _validate_parser().parse_args(argv)
    mission, trois = load_mission(a.mission)
    check_hardware_files(mission, a.mission)
    robot_model(mission)  # the URDF, its flange frame and joint count, before the maps take seconds
    problem = _output_problem(Path(mission.output.dir))
    if problem:
        raise MissionError([f"{mission.where('output', 'dir')}: output.dir: {problem}"])
    plan_check(mission, trois, a.mission)  # the maps as run makes them (cached: the run reuses them)
    print(f"{a.mission}: ok — {len(trois)} TROIs, planner {mission.planner}, drivers {mission.drivers.kind}")
    for w in _link_warnings(mission) + fuel_warnings(mission, len(trois)) + overlap_warnings(trois):
        print(f"{a.mission}: warning: {w}", file=sys.stderr)
    return 0


def plan_check(mission: Mission, trois: list, mission_path: str | Path, quiet: bool = False, tail: str = ""):
    """(robot, core, planner) for this mission, or UserError (exit 2): the reachability maps (from
    the cache, or built with progress lines on stderr unless `quiet`), the planning core and the
    planner, and every TROI plannable. A robot/task inside every bound whose geometry admits no plan
    (R_m empty, a flame that may not tilt) fails here; `validate` and `run` both call it, `run`
    before anything is written. `tail` ends the error line."""
    from capm_field.config import ReachabilityConfig
    from capm_field.planners import PlanningCore, make_planner
    from capm_field.reachability import get_maps

    say = (lambda m: None) if quiet else (lambda m: print(f"reachability maps: {m}", file=sys.stderr))
    try:
        robot = robot_model(mission)
        maps = get_maps(robot, mission.task, ReachabilityConfig(), progress=say)
        core = PlanningCore(robot, maps, mission.task)
        for t in trois:
            core.effective_radius(t.r)  # every TROI must be plannable before anything starts
        planner = make_planner(mission.planner, core, seed=mission.drivers.seed if mission.drivers.kind == "bench" else 0)
    except UserError as e:
        raise UserError(f"{mission_path}: {e}{tail}") from e
    except Exception as e:  # noqa: BLE001 - a robot/task the schema allows but the geometry cannot use
        raise UserError(f"{mission_path}: robot/task: no plan can be made with these values ({type(e).__name__}: "
                        f"{' '.join(str(e).split())[:200]}){tail}") from e
    return robot, core, planner


def _output_problem(out: Path) -> str | None:
    """Why `out` cannot take a run's files, or None. Checked before anything starts: a directory
    named summary.json was found by the summary's os.replace after the whole mission, one named
    run.mcap by the run log after the drivers had opened."""
    if out.exists() and not out.is_dir():
        return f"{out} exists and is not a directory"
    for name in OUTPUTS + ("summary.json.tmp",):
        p = out / name
        if (p.exists() or p.is_symlink()) and not p.is_file():
            return f"{p} is {'a directory' if p.is_dir() else 'not a regular file'}, where the run writes a file"
    return None


def _write_new(path: Path, text: str) -> None:
    """`text` into a new file at `path`: whatever is there (a crashed run's temp file, or a link
    planted to make the run write elsewhere) is removed first, and the file is created exclusively
    (O_EXCL never follows a link: one put back in between is an error, not a write through it)."""
    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)


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
    ap.add_argument("--faults", help="bench fault schedule: 'random:SEED' or KIND@TARGET[,KIND@TARGET...]; '' runs without the mission's own (drivers.faults)")
    ap.add_argument("--quiet", action="store_true", help="no progress lines and no result line (summary.json has the result; errors and warnings still print)")
    ap.add_argument("--force", action="store_true", help="overwrite run.mcap/summary.json already in the output directory")
    return ap


class _Progress:
    """One status line on a terminal (target i/N, phase, energy so far); plain lines otherwise."""

    def __init__(self, enabled: bool):
        self.enabled = enabled
        self.tty = sys.stderr.isatty()
        self._last = ""
        self._t0 = time.monotonic()

    def __call__(self, s: dict) -> None:
        if not self.enabled:
            return
        i, n = s["index"], s["total"]
        elapsed = time.monotonic() - self._t0
        # the time left from the targets done so far (none yet: not guessed)
        eta = f" · left ~{_hms(elapsed / i * (n - i))}" if 0 < i < n else ""
        line = (f"target {min(i + 1, n)}/{n} {s['target']:<6} {s['phase']:<20} energy {s['energy']:7.2f}"
                f" · flamed {s.get('flamed', 0)} skipped {s.get('skipped', 0)} · {_hms(elapsed)}{eta}")
        skip = s["phase"].startswith("skipped")
        if self.tty and not skip:
            sys.stderr.write("\r" + line.ljust(len(self._last)))
            sys.stderr.flush()
            self._last = line
        elif self.tty:  # a skip stays on screen, above the status line
            sys.stderr.write("\r" + line.ljust(len(self._last)) + "\n")
            sys.stderr.flush()
            self._last = ""
        elif s["phase"] in ("plan", "done", "ordering") or skip:
            print(line, file=sys.stderr)

    def close(self) -> None:
        if self.enabled and self.tty:
            sys.stderr.write("\n")


def _hms(seconds: float) -> str:
    m, sec = divmod(int(seconds), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{sec:02d}" if h else f"{m}:{sec:02d}"


def _open_drivers(mission: Mission, robot, trois, seed: int | None, mission_dir: Path):
    if mission.drivers.kind == "bench":
        from sim_bench.bench_drivers import open_bench_drivers  # dynamic choice, the executive can't tell

        s = mission.drivers.seed if seed is None else seed
        return open_bench_drivers(robot, mission.task, trois, mission.start.se2(), s, mission.drivers.mpoi_in_troi, mission.drivers.transport)
    mod = importlib.import_module("drivers.hardware")
    return mod.open_hardware_drivers(mission, robot, mission_dir)


def _stop_signal(signum: int, frame) -> None:
    # `systemctl stop`, a supervisor (SIGTERM); the operator's SSH session or terminal gone (SIGHUP):
    # end as Ctrl-C does (flame off, summary marked interrupted)
    raise KeyboardInterrupt(signal.Signals(signum).name)


class _Console:
    """sys.stdout / sys.stderr for a run: a console that goes away (the terminal hung up: EIO; the
    reader of a pipe gone: EPIPE) does not stop the mission nor skip its ending. The first failed
    write is kept in `lost` and later ones are dropped: progress lines and messages are for the
    operator, the run log and summary.json are the record."""

    def __init__(self, stream) -> None:
        self.stream = stream
        self.lost: OSError | ValueError | None = None

    def write(self, text: str) -> int:
        if self.lost is None:
            try:
                return self.stream.write(text)
            except (OSError, ValueError) as e:  # (ValueError: the stream was closed)
                self.lost = e
        return len(text)

    def flush(self) -> None:
        if self.lost is None:
            try:
                self.stream.flush()
            except (OSError, ValueError) as e:
                self.lost = e

    def __getattr__(self, name: str):
        return getattr(self.stream, name)


def main(argv: list[str]) -> int:
    a = _run_parser().parse_args(argv)
    previous: dict[int, object] = {}
    if threading.current_thread() is threading.main_thread():
        # (one the process was started ignoring stays ignored: `nohup capm-field run …` outlives the SSH session)
        previous = {s: signal.signal(s, _stop_signal) for s in STOP_SIGNALS if signal.getsignal(s) is not signal.SIG_IGN}
    consoles = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = _Console(sys.stdout), _Console(sys.stderr)
    try:
        return _run(a)
    except KeyboardInterrupt as e:  # before or after the mission (the executive ends its own)
        if str(e) not in {s.name for s in STOP_SIGNALS}:
            raise
        print(f"capm-field run: interrupted ({e})", file=sys.stderr)
        return 128 + signal.Signals[str(e)]
    finally:
        lost = [c for c, w in zip(consoles, (sys.stdout, sys.stderr)) if isinstance(w, _Console) and w.lost is not None]
        sys.stdout, sys.stderr = consoles
        for stream in lost:  # the interpreter's flush at exit would fail again (exit 120): point it nowhere
            try:
                null = os.open(os.devnull, os.O_WRONLY)
                try:
                    os.dup2(null, stream.fileno())
                finally:
                    os.close(null)
            except (OSError, ValueError, AttributeError):  # (a console without a file descriptor: nothing to point)
                pass
        for s, h in previous.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)


def _run(a: argparse.Namespace) -> int:
    mission, trois = load_mission(a.mission)
    check_hardware_files(mission, a.mission)
    for w in overlap_warnings(trois):
        print(f"capm-field run: warning: {w}", file=sys.stderr)
    faults = []
    if mission.drivers.kind == "bench":
        from sim_bench.faults import bench_faults

        spec = a.faults if a.faults is not None else mission.drivers.faults
        faults = bench_faults(spec, len(trois), mission.drivers.transport)  # before anything is written
    elif a.faults or a.seed is not None:
        raise UserError("--faults and --seed apply to bench missions only (drivers.kind: bench)")
    if a.out == "":  # Path("") is the current directory: an empty --out was silently the mission's output.dir
        raise UserError("--out: empty directory name (nothing was started)")
    out = Path(a.out if a.out is not None else mission.output.dir)
    problem = _output_problem(out)
    if problem:
        raise UserError(f"--out: {problem} (nothing was started)")
    taken = [out / n for n in OUTPUTS if (out / n).exists()]
    if taken and not a.force:
        raise UserError(f"{taken[0]} already exists: choose another --out or pass --force (nothing was started)")

    from .executive import Executive
    from .runlog import RunLogHandler

    quiet = a.quiet
    robot, core, planner = plan_check(mission, trois, a.mission, quiet, " (nothing was started)")
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
    log = _open_log(out, made, drivers, robot, mission, a, bench=world is not None)
    closing = HeldSignals()  # once the mission has returned, Ctrl-C is noted: the summary is still written
    try:
        progress = _Progress(not quiet)
        to_runlog = RunLogHandler(log, now_ns)
        try:  # from here on the drivers and the log are closed whatever happens
            hook = None
            if world is not None:
                from sim_bench.faults import FaultInjector

                if faults:
                    injector = FaultInjector(faults, drivers, log_event=lambda lvl, msg: log.event(now_ns(), lvl, msg))
                    hook = injector.on
            # warnings and errors of the software's Python loggers go to the console and into the run log
            logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
            logging.getLogger().addHandler(to_runlog)
            ex = Executive(trois, mission.start.se2(), mission.end_pose(), drivers, core, planner, log=log, progress=progress, truth=truth, now_ns=now_ns, timeouts=mission.timeouts, hook=hook,
                           fuel_per_s=mission.igniter.fuel_per_s, fuel_reserve=mission.igniter.fuel_reserve)
            result = ex.run()
        finally:
            closing.start()
            logging.getLogger().removeHandler(to_runlog)
            progress.close()
            try:
                drivers.close()
            finally:
                log.close()
        summary = result.to_json()
        summary["log_s"] = log.call_time_s  # time spent in RunLog calls (logging cost)
        if log.write_error:  # the run log stopped taking writes (disk full …): it ends there
            summary["log_error"] = log.write_error
        summary.update({"name": mission.name, "mission": str(a.mission), "planner": mission.planner,
                        "seed": a.seed if a.seed is not None else getattr(mission.drivers, "seed", None), "images": mission.output.images})
        tmp = out / "summary.json.tmp"
        try:
            _write_new(tmp, json.dumps(summary, indent=1))
            os.replace(tmp, out / "summary.json")
        except OSError as e:  # (a full disk): the run is over, its summary must not be lost
            try:
                tmp.unlink(missing_ok=True)
            except OSError:
                pass
            print(f"capm-field run: cannot write {out / 'summary.json'}: {e.strerror or e}; the summary follows on stdout", file=sys.stderr)
            if not (out / "run.mcap").is_file():  # the directory removed (or replaced) while the run wrote into it
                print(f"capm-field run: {out / 'run.mcap'} is gone: the output directory was removed during the run, "
                      "and the run log with it", file=sys.stderr)
            print(json.dumps(summary))
            return 1
        flamed = sum(t.flamed for t in result.targets)
        if not quiet:
            print(
                f"{flamed}/{len(result.targets)} flamed, success rate {result.success_rate:.2f}, energy {result.total_energy:.2f}, "
                f"wall {result.wall_s:.1f} s (logging {log.call_time_s:.2f} s, {100 * log.call_time_s / max(result.wall_s, 1e-9):.1f} %) → {out}/run.mcap, {out}/summary.json"
            )
        if log.write_error:
            print(f"capm-field run: run log {out / 'run.mcap'} incomplete (readable up to the failure): {log.write_error}", file=sys.stderr)
        if result.interrupted:
            print(f"capm-field run: interrupted ({result.interrupted}): flame off, body stopped; {out / 'summary.json'} marked interrupted", file=sys.stderr)
            return 128 + signal.Signals[result.interrupted]
        if result.aborted:
            print(f"capm-field run: mission aborted: {result.aborted}", file=sys.stderr)
            return 1
        return 1 if log.write_error else 0
    finally:
        closing.stop()


def _open_log(out: Path, made: bool, drivers, robot, mission: Mission, a: argparse.Namespace, *, bench: bool):
    """The run log, opened once the drivers are; if it cannot be, the drivers are closed again
    (igniter first) before the error. With --force the previous run's summary goes as its log is
    reopened: it must not sit beside a new run that may end before writing its own."""
    from .runlog import RunLog

    try:
        log = RunLog(out / "run.mcap", robot, _camera(robot), bench=bench, overwrite=a.force, images=mission.output.images,
                     image_format=mission.output.image_format, metadata={"mission_name": mission.name, "mission": str(a.mission)})
        try:
            (out / "summary.json").unlink(missing_ok=True)
        except BaseException:
            log.close()
            raise
    except Exception as e:
        drivers.close()
        if made and out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        raise UserError(f"cannot create the run log {out / 'run.mcap'}: {getattr(e, 'strerror', None) or e} "
                        "(nothing was started; drivers closed)") from e
    except BaseException:
        drivers.close()
        raise
    return log


def _camera(robot):
    from capm_field.camera import PinholeCamera

    return PinholeCamera.from_config(robot.cfg.camera)


__all__ = ["main", "validate_main", "MissionError"]
