"""Shared fixtures: the default robot, task and reachability maps (built once, cached on disk);
a raw CAN host on the simulated gateway."""

from __future__ import annotations

import os

import pytest
from hypothesis import settings

from capm_field.config import ReachabilityConfig, RobotConfig, TaskConfig
from capm_field.planners import PlanningCore
from capm_field.reachability import Regions, get_maps
from capm_field.robot_model import RobotModel

# CI (`.ci/run` sets HYPOTHESIS_PROFILE=ci): the same draws on every run, so a submission is judged on
# the code, not on a fresh random draw; local runs keep drawing new examples (a failure they find is
# pinned with @example)
settings.register_profile("ci", derandomize=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


@pytest.fixture
def cli_run(capsys):
    """`capm-field ARGS` in this process, answered as `subprocess.run(..., capture_output=True,
    text=True)` would. No interpreter start-up and imports (~1.7 s a subprocess call): for tests of
    refusals; end-to-end runs use a subprocess."""
    import subprocess

    from capm_field import cli

    def run(args: list[str]) -> subprocess.CompletedProcess:
        capsys.readouterr()
        try:
            rc = cli.main(args)
        except SystemExit as e:  # argparse's usage errors
            rc = e.code if isinstance(e.code, int) else 1
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess(args, rc, out, err)

    return run


@pytest.fixture(scope="session")
def robot() -> RobotModel:
    return RobotModel(RobotConfig())


@pytest.fixture(scope="session")
def task() -> TaskConfig:
    return TaskConfig(gamma=0.5)


@pytest.fixture(scope="session")
def maps(robot, task):
    return get_maps(robot, task, ReachabilityConfig())


@pytest.fixture(scope="session")
def regions(robot, maps) -> Regions:
    return Regions(robot, maps)


@pytest.fixture(scope="session")
def core(robot, maps, task) -> PlanningCore:
    return PlanningCore(robot, maps, task)


@pytest.fixture
def raw():
    """(CanBench with the robot side only, RawHost on its virtual bus), once the gateway's status
    and the host's heartbeats have been seen by both ends."""
    import time

    from sim_bench.can_rig import CanBench, RawHost

    bench = CanBench(with_arm=False, with_igniter=False)
    host = RawHost(bench.bus)
    try:
        assert host.wait_ign(lambda s: True, 2.0) is not None
        rs = bench.robot_side
        end = time.monotonic() + 2.0
        while not (rs.board.host_present and rs._host_arm_hb is not None) and time.monotonic() < end:
            time.sleep(0.005)
        assert rs.board.host_present and rs._host_arm_hb is not None  # host heartbeats seen
        host.start_up()  # counters taken up, resync hold over: the test's first command is acted on
        yield bench, host
    finally:
        host.close()
        bench.close()
