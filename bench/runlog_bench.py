"""Logging cost of the run log: a synthetic 15-target mission through RunLog, timed per method.

    .venv/bin/python bench/runlog_bench.py [--targets 15] [--seconds-per-target 4] [--images-per-target 2] [--out DIR]

Prints the wall time spent inside RunLog calls (what the executive pays), per method, the
file size and the number of background flushes. Timings are noisy on shared cores.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig, RobotConfig
from capm_field.robot_model import RobotModel
from mission.runlog import RunLog
from mission.runlog_read import ReadReport, iter_run
from mission.runlog_synth import TF_HZ, Timed, synthetic_mission


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", type=int, default=15)
    ap.add_argument("--seconds-per-target", type=float, default=4.0, help="sim seconds per target (transforms at 20 Hz)")
    ap.add_argument("--images-per-target", type=int, default=2)
    ap.add_argument("--flush-period", type=float, default=0.5)
    ap.add_argument("--out", type=Path, help="keep run.mcap in this directory")
    args = ap.parse_args()

    robot = RobotModel(RobotConfig())
    cam = PinholeCamera.from_config(CameraConfig())
    with tempfile.TemporaryDirectory() as tmp:
        path = (args.out or Path(tmp)) / "run.mcap"
        path.unlink(missing_ok=True)
        log = Timed(RunLog(path, robot, cam, bench=True, flush_period_s=args.flush_period))
        t0 = time.perf_counter()
        synthetic_mission(log, n_targets=args.targets, seconds_per_target=args.seconds_per_target, images_per_target=args.images_per_target)
        wall = time.perf_counter() - t0
        log.close()
        report = ReadReport()
        n = sum(1 for _ in iter_run(path, report=report))
        size = path.stat().st_size
        flushes = log._log.n_flushes

    total = sum(log.seconds.values())
    sim_s = args.targets * args.seconds_per_target
    print(f"mission: {args.targets} targets, {sim_s:.0f} s sim time, transforms at {TF_HZ} Hz, "
          f"{log.calls['image']} images {cam.width}x{cam.height}, {sum(log.calls.values())} RunLog calls")
    print(f"time in RunLog calls: {total * 1e3:.1f} ms total ({total / sim_s * 100:.2f} % of sim time); loop wall {wall * 1e3:.0f} ms")
    for name in sorted(log.seconds, key=log.seconds.get, reverse=True):
        c = log.calls[name]
        print(f"  {name:<12} {c:>6} calls  {log.seconds[name] * 1e3:8.1f} ms  {log.seconds[name] / c * 1e6:8.1f} us/call")
    print(f"file: {size / 1e6:.2f} MB, {n} messages read back (complete={report.complete}), {flushes} background flushes")


if __name__ == "__main__":
    main()
