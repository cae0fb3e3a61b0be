"""Shared fixtures: the default robot, task and reachability maps (built once, cached on disk)."""

from __future__ import annotations

import pytest

from capm_field.config import ReachabilityConfig, RobotConfig, TaskConfig
from capm_field.planners import PlanningCore
from capm_field.reachability import Regions, get_maps
from capm_field.robot_model import RobotModel


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
