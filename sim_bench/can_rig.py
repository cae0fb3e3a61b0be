"""A wired CAN bench in one process: `CanRobotSide` + the real `CanArm` / `CanIgniter` adapters
on one python-can `virtual` channel of their own (tests, bench-drivers, bench missions)."""

from __future__ import annotations

import itertools
import os
import threading
import time

import can

from capm_field.robot_model import RobotModel
from drivers.can.codec import (ARM_NOP, IGN_ARM, IGN_IGNITE, IGN_NOP, NODE_HOST_ARM, NODE_HOST_IGN, RESYNC_HOLD_S, Encoder,
                               Receiver)
from drivers.can.config import CanArmConfig, CanBusConfig, CanIgniterConfig, HeartbeatConfig
from drivers.can.link import open_bus
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
        arm_state_timeout: float | None = None,
    ) -> None:
        self.robot = robot or RobotModel()
        self.bus = CanBusConfig(interface="virtual", channel=unique_channel())
        hb = HeartbeatConfig(timeout=heartbeat_timeout)
        self.robot_side = CanRobotSide(self.bus, robot=self.robot, igniter=igniter, host_timeout=heartbeat_timeout)
        self.arm: CanArm | None = None
        self.igniter: CanIgniter | None = None
        try:
            if with_arm:
                extra = {} if arm_state_timeout is None else {"state_timeout": arm_state_timeout}
                self.arm = CanArm(CanArmConfig(bus=self.bus, heartbeat=hb, **extra), robot=self.robot)
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


class RawHost(can.Listener):
    """A bare host node without an adapter: sends exactly the frames it is told to (to play a
    frozen host, a replaying or corrupting sender) and records the igniter/arm status frames."""

    def __init__(self, bus_cfg: CanBusConfig, heartbeat_period: float | None = 0.1) -> None:
        self.enc = Encoder()
        self.rx = Receiver({"IGN_STATUS", "ARM_STATUS"})
        self._cv = threading.Condition()
        self.ign_status: dict | None = None
        self.ign_status_t = 0.0
        self.ign_history: list[tuple[float, dict]] = []  # (receive time, IGN_STATUS) of every status
        self._hb_stop = threading.Event()
        self.bus = open_bus(bus_cfg)
        self.notifier = can.Notifier(self.bus, [self], timeout=0.05)
        self._hb_thread = None
        if heartbeat_period:
            self._hb_thread = threading.Thread(target=self._beat, args=(heartbeat_period,), daemon=True)
            self._hb_thread.start()

    def _beat(self, period: float) -> None:
        while not self._hb_stop.is_set():
            self.send(self.enc.heartbeat("HB_HOST_IGN", NODE_HOST_IGN, period))
            self.send(self.enc.heartbeat("HB_HOST_ARM", NODE_HOST_ARM, period))
            self._hb_stop.wait(period)

    def stop_heartbeat(self) -> None:
        self._hb_stop.set()
        if self._hb_thread is not None:
            self._hb_thread.join(1.0)

    def on_message_received(self, msg: can.Message) -> None:
        got = self.rx.accept(msg)
        if got and got[0] == "IGN_STATUS":
            with self._cv:
                self.ign_status, self.ign_status_t = got[1], time.monotonic()
                self.ign_history.append((self.ign_status_t, got[1]))
                self._cv.notify_all()

    def statuses_since(self, t0: float) -> list[dict]:
        with self._cv:
            return [st for t, st in self.ign_history if t >= t0]

    def send(self, msg: can.Message) -> float:
        self.bus.send(msg)
        return time.monotonic()

    def start_up(self) -> None:
        """The host start-up's essentials (docs/protocols/can.md): one NOP per command id takes up
        the nodes' counters (first frame or resync), then wait out their resync hold (rule 7), so
        the next real command is acted on."""
        self.ign(IGN_NOP)
        self.arm_cmd(ARM_NOP)
        time.sleep(RESYNC_HOLD_S + 0.01)

    def ign(self, cmd: int, counter: int | None = None) -> float:
        """Send one IGN_CMD; returns the monotonic time right after sending."""
        return self.send(self.enc.encode("IGN_CMD", {"Command": cmd}, counter=counter))

    def arm_cmd(self, cmd: int, counter: int | None = None) -> float:
        """Send one ARM_CMD; returns the monotonic time right after sending."""
        return self.send(self.enc.encode("ARM_CMD", {"Command": cmd}, counter=counter))

    def target_half(self, half: str, q3, counter: int) -> float:
        """Send ARM_TARGET_A (half 'A', joints 1-3) or ARM_TARGET_B ('B', joints 4-6) with `counter`."""
        j = (1, 2, 3) if half == "A" else (4, 5, 6)
        sig = {f"J{k}_Target": float(v) for k, v in zip(j, q3)}
        return self.send(self.enc.encode(f"ARM_TARGET_{half}", sig, counter=counter))

    def next_target_counter(self) -> int:
        """The next shared counter value of a target set (both ids advance together)."""
        c = self.enc.next_counter("ARM_TARGET_A")
        self.enc.next_counter("ARM_TARGET_B")
        return c

    def light(self, timeout: float = 3.0) -> float:
        """ARM, then IGNITE every 20 ms until FlameOn; re-ARMs if the board tripped meanwhile (a
        host stall > 80 ms on a loaded machine). Returns the time the flame was seen lit."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.ign(IGN_ARM)
            if self.wait_ign(lambda s: s["Armed"] == 1, 1.0) is None:
                continue
            nxt = time.monotonic()
            while time.monotonic() < end:
                self.ign(IGN_IGNITE)
                nxt += 0.02
                t_lit = self.wait_ign(lambda s: s["FlameOn"] == 1 or s["Armed"] == 0, max(0.0, nxt - time.monotonic()))
                if t_lit is not None:
                    if self.ign_status["FlameOn"] == 1:
                        return t_lit
                    break  # tripped: ARM again
        raise RuntimeError("igniter did not light")

    def wait_ign(self, pred, timeout: float) -> float | None:
        """Wait for an IGN_STATUS satisfying pred; returns its receive time or None."""
        end = time.monotonic() + timeout
        with self._cv:
            while self.ign_status is None or not pred(self.ign_status):
                left = end - time.monotonic()
                if left <= 0:
                    return None
                self._cv.wait(left)
            return self.ign_status_t

    def close(self) -> None:
        self.stop_heartbeat()
        self.notifier.stop(timeout=1.0)
        self.bus.shutdown()
