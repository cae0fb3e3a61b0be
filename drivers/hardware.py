"""The robot: a DriverSet of the real adapters, opened from a mission file's `drivers: {kind: hardware}`.

Body: zenoh client to `capm-field spot-bridge` (TLS/ACL via `zenoh.config_file`, docs/security.md);
arm and igniter: CAN (`can.interface`/`can.channel`, socketcan on the robot); camera: OpenCV.
Opening is all-or-nothing: if one adapter fails, the ones already open are closed again.
"""

from __future__ import annotations

from pathlib import Path

from capm_field.robot_model import RobotModel

from .can.config import CanArmConfig, CanBusConfig, CanIgniterConfig
from .interfaces import DriverError, DriverSet


def open_hardware_drivers(mission, robot: RobotModel, mission_dir: str | Path | None = None) -> DriverSet:
    from .can_arm import CanArm
    from .can_igniter import CanIgniter
    from .opencv_camera import OpenCVCamera
    from .zenoh_body import ZenohBody, ZenohBodyConfig

    hw = mission.drivers
    bus = CanBusConfig(interface=hw.can.interface, channel=hw.can.channel, bitrate=hw.can.bitrate)
    opened: list = []
    try:
        igniter = CanIgniter(CanIgniterConfig(bus=bus))
        opened.append(igniter)
        igniter.extinguish()  # whatever state the board was left in: flame off first
        arm = CanArm(CanArmConfig(bus=bus), robot)
        opened.append(arm)
        try:
            body = ZenohBody(ZenohBodyConfig.from_spec(hw.zenoh, mission_dir))
        except DriverError:
            raise
        except Exception as e:  # zenoh refusing its config or endpoints: a driver that cannot open
            raise DriverError(f"body link: cannot open the zenoh session: {' '.join(str(e).split())[:300]}") from e
        opened.append(body)
        camera = OpenCVCamera(hw.camera.source, mission.robot.camera, fourcc=hw.camera.fourcc)
        opened.append(camera)
    except BaseException:
        for d in reversed(opened):
            try:
                d.close()
            except Exception:  # noqa: BLE001 - close the rest regardless
                pass
        raise
    return DriverSet(body, arm, igniter, camera)
