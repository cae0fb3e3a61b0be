"""Fault paths found by an adversarial audit (faults at the worst moment, a failing run log,
signals mid-burn, wire links frozen mid-hold): each test failed before its fix."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

# ---- the run log's file stops taking writes (disk full; here a file size limit) ------------------
_LOG_FAILS = textwrap.dedent("""\
    import logging, os, resource, sys, threading, time
    from capm_field.config import RobotConfig
    from capm_field.camera import PinholeCamera
    from capm_field.robot_model import RobotModel
    from mission.runlog import RunLog, RunLogHandler
    robot = RobotModel(RobotConfig())
    log = RunLog(sys.argv[1], robot, PinholeCamera.from_config(robot.cfg.camera), bench=True,
                 flush_period_s=3600, chunk_size=16 * 1024)
    logging.basicConfig(level=logging.WARNING)
    logging.getLogger().addHandler(RunLogHandler(log, time.time_ns))
    resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
    def work():
        for i in range(200):  # ~400 KB of incompressible text: the file stops at 64 KiB
            log.event(time.time_ns(), "info", os.urandom(1000).hex())
        log.flush()
        log.close()
    t = threading.Thread(target=work, daemon=True)
    t.start()
    t.join(20)
    print("HUNG" if t.is_alive() else f"DONE {log.write_error}")
    sys.stdout.flush()
    os._exit(0)
""")


def test_run_log_write_failure_does_not_deadlock(tmp_path):
    """A write error of the MCAP sink (ENOSPC, EFBIG) is reported by foxglove-sdk as a Python log
    warning from inside the write, with RunLog's lock held; RunLogHandler (on the root logger, as
    `capm-field run` installs it) turned it into a RunLog.event on the same thread: the run hung for
    good on that lock (mid-flame on the wire bench: no keep-alives, no exit, no summary)."""
    r = subprocess.run([sys.executable, "-c", _LOG_FAILS, str(tmp_path / "run.mcap")], capture_output=True, text=True, timeout=60)
    assert "DONE" in r.stdout, (r.stdout, r.stderr[-2000:])
    assert "File too large" in r.stdout, r.stdout  # the first failure is kept for the run to report
    # one console line about it, not one per message written after it
    assert r.stderr.count("error logging message") <= 1, r.stderr[-2000:]
