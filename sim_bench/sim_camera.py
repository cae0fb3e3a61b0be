"""Bench camera: renders the field scene from the pose the sim arm/body report.

`pose_fn()` returns T_field_cam (4×4) at capture time. Fault hooks make the next N captures
time out (`inject_drop`) or return a black frame (`inject_black`), for executive tests.
"""

from __future__ import annotations

import threading
import time
from typing import Callable

import numpy as np

from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig
from drivers.interfaces import Camera, DriverError, DriverTimeout, Frame

from .field_scene import FieldScene


class SimCamera(Camera):
    def __init__(
        self,
        scene: FieldScene,
        pose_fn: Callable[[], np.ndarray],
        config: CameraConfig | None = None,
        clock_ns: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self._scene = scene
        self._pose_fn = pose_fn
        self._cam = PinholeCamera.from_config(config or CameraConfig())
        self._clock_ns = clock_ns
        self._lock = threading.Lock()
        self._drop = 0
        self._black = 0
        self._closed = False

    @property
    def intrinsics(self) -> PinholeCamera:
        return self._cam

    def inject_drop(self, n: int = 1) -> None:
        """The next `n` captures raise DriverTimeout (frame never arrives)."""
        with self._lock:
            self._drop += int(n)

    def inject_black(self, n: int = 1) -> None:
        """The next `n` captures return an all-black frame (lens covered, exposure fault)."""
        with self._lock:
            self._black += int(n)

    def capture(self, timeout: float) -> Frame:
        if self._closed:
            raise DriverError("camera is closed")
        with self._lock:
            drop = self._drop > 0
            black = not drop and self._black > 0
            self._drop -= drop
            self._black -= black
        if drop:
            time.sleep(max(0.0, min(timeout, 0.05)))  # keep fault tests fast; the caller asked for a timeout
            raise DriverTimeout(f"no frame within {timeout:.3f} s (injected drop)")
        T = np.asarray(self._pose_fn(), float)
        stamp = self._clock_ns()
        if black:
            img = np.zeros((self._cam.height, self._cam.width, 3), np.uint8)
        else:
            img = self._scene.render(T, self._cam)
        return Frame(image=img, stamp_ns=stamp, intrinsics=self._cam, camera_pose_field=T.copy())

    def close(self) -> None:
        self._closed = True
