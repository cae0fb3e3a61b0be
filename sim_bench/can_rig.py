"""A wired CAN bench in one process: `CanRobotSide` + the real `CanArm` / `CanIgniter` adapters
on one python-can `virtual` channel of their own (tests, bench-drivers, bench missions)."""

from __future__ import annotations

import itertools
import os

from capm_field.robot_model import RobotModel
from drivers.can.config import CanArmConfig, CanBusConfig, CanIgniterConfig, HeartbeatConfig
from drivers.can_arm import CanArm
from drivers.can_igniter import CanIgniter

from .can_robot_side import CanRobotSide
from .sim_igniter import IgniterParams

_seq = itertools.count()


def unique_channel(prefix: str = "capm") -> str:
    """A virtual channel name no other bench in this process uses."""
    return f"{prefix}-{os.getpid()}-{next(_seq)}"


class CanBench:
    def __init__(
        self,
        robot: RobotModel | None = None,
        igniter: IgniterParams | None = None,
        heartbeat_timeout: float = 0.3,
        with_arm: bool = True,
        with_igniter: bool = True,
    ) -> None:
        self.robot = robot or RobotModel()
        self.bus = CanBusConfig(interface="virtual", channel=unique_channel())
        hb = HeartbeatConfig(timeout=heartbeat_timeout)
        self.robot_side = CanRobotSide(self.bus, robot=self.robot, igniter=igniter, host_timeout=heartbeat_timeout)
        self.arm: CanArm | None = None
        self.igniter: CanIgniter | None = None
        try:
            if with_arm:
                self.arm = CanArm(CanArmConfig(bus=self.bus, heartbeat=hb), robot=self.robot)
            if with_igniter:
                self.igniter = CanIgniter(CanIgniterConfig(bus=self.bus, heartbeat=hb))
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        for d in (self.igniter, self.arm):  # igniter first: flame off
            if d is not None:
                d.close()
        self.robot_side.close()

    def __enter__(self) -> "CanBench":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
