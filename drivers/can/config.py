"""Configuration of the CAN adapters (bus, node ids, timing). Defaults are the protocol's.

`interface`/`channel` are python-can's: `socketcan`/`can0` on the robot, `virtual`/<any name>
on the bench (python-can `virtual` reaches only buses opened in the same process).
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class CanBusConfig(_Frozen):
    interface: str = Field("virtual", description="python-can interface: 'socketcan' on the robot, 'virtual' on the bench")
    channel: str = Field("capm0", description="python-can channel ('can0' on the robot)")
    bitrate: int | None = Field(None, description="only for interfaces that set it themselves (socketcan: set by `ip link`)")


class HeartbeatConfig(_Frozen):
    period: float = Field(0.1, gt=0.0, description="own heartbeat producer period (s)")
    timeout: float = Field(0.3, gt=0.0, description="peer heartbeat consumer timeout (s) -> LinkLost")


class CanArmConfig(_Frozen):
    bus: CanBusConfig = Field(default_factory=CanBusConfig)
    heartbeat: HeartbeatConfig = Field(default_factory=HeartbeatConfig)
    stream_rate_hz: float = Field(500.0, gt=0.0, le=1000.0, description="joint-target streaming rate")
    at_target_tol: float = Field(2e-3, gt=0.0, description="joint error (rad) at which a move counts as arrived")
    enable_timeout: float = Field(0.5, gt=0.0, description="wait for the gateway to report ENABLED (s)")
    max_counter_jump: int = Field(3, ge=1, le=14, description="largest accepted counter step (>1: frames lost)")
    state_timeout: float = Field(0.25, gt=0.0, description="joint state older than this during a move -> STOP, 'state_stale' (s)")


class CanIgniterConfig(_Frozen):
    bus: CanBusConfig = Field(default_factory=CanBusConfig)
    heartbeat: HeartbeatConfig = Field(default_factory=HeartbeatConfig)
    keepalive_rate_hz: float = Field(50.0, gt=0.0, le=200.0, description="IGNITE keep-alive rate while the permit holds")
    poll_period: float = Field(0.005, gt=0.0, le=0.02, description="how often ignite() re-checks permit() and status (s)")
    status_timeout: float = Field(0.25, gt=0.0, description="igniter status older than this during ignite() -> off, 'status_stale' (s)")
    max_counter_jump: int = Field(3, ge=1, le=14)
