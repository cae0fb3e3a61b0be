"""Hardware camera over OpenCV: a device index, a URI (rtsp://, http://, file) or a GStreamer
pipeline string. Intrinsics come from CameraConfig (calibrated values go in the mission file).

A reader thread keeps only the newest frame, so `capture()` returns a fresh image instead of a
stale one from the driver's buffer, and a hung device cannot block the caller past `timeout`.
"""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np

from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig

from .interfaces import Camera, DriverError, DriverTimeout, Frame


class OpenCVCamera(Camera):
    def __init__(self, source: int | str, config: CameraConfig | None = None, open_timeout: float = 5.0) -> None:
        self._cfg = config or CameraConfig()
        self._cam = PinholeCamera.from_config(self._cfg)
        self._source = source
        self._cond = threading.Condition()
        self._frame: np.ndarray | None = None
        self._stamp = 0
        self._seq = 0
        self._error: str | None = None
        self._stop = threading.Event()
        self._cap = self._open(source, open_timeout)
        self._thread = threading.Thread(target=self._reader, name="opencv-camera", daemon=True)
        self._thread.start()

    # ---- Camera ----------------------------------------------------------------------------
    @property
    def intrinsics(self) -> PinholeCamera:
        return self._cam

    def capture(self, timeout: float) -> Frame:
        """Wait for a frame newer than the call (BGR uint8, resized to the configured size)."""
        deadline = time.monotonic() + max(0.0, timeout)
        with self._cond:
            seq0 = self._seq
            while self._seq == seq0:
                if self._error:
                    raise DriverError(f"camera {self._source!r}: {self._error}")
                left = deadline - time.monotonic()
                if left <= 0 or self._stop.is_set():
                    raise DriverTimeout(f"camera {self._source!r}: no frame within {timeout:.3f} s")
                self._cond.wait(left)
            img, stamp = self._frame, self._stamp
        return Frame(image=img, stamp_ns=stamp, intrinsics=self._cam, camera_pose_field=None)

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        self._thread.join(timeout=1.0)
        try:
            self._cap.release()
        except Exception:  # noqa: BLE001 - closing must not raise
            pass

    # ---- internals ---------------------------------------------------------------------------
    def _open(self, source: int | str, timeout: float) -> cv2.VideoCapture:
        params = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, int(timeout * 1000), cv2.CAP_PROP_READ_TIMEOUT_MSEC, int(timeout * 1000)]
        if isinstance(source, str) and ("!" in source and "appsink" in source):
            cap = cv2.VideoCapture(source, cv2.CAP_GSTREAMER)
        else:
            cap = cv2.VideoCapture(source, cv2.CAP_ANY, params)
        if not cap.isOpened():
            cap.release()
            raise DriverError(f"cannot open camera {source!r}")
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, self._cfg.width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self._cfg.height)
        return cap

    def _reader(self) -> None:
        fails = 0
        while not self._stop.is_set():
            ok, img = self._cap.read()
            if not ok or img is None:
                fails += 1
                if fails >= 50:
                    with self._cond:
                        self._error = "stream ended or device lost"
                        self._cond.notify_all()
                    return
                time.sleep(0.02)
                continue
            fails = 0
            img = self._to_bgr(img)
            with self._cond:
                self._frame, self._stamp = img, time.monotonic_ns()
                self._seq += 1
                self._cond.notify_all()

    def _to_bgr(self, img: np.ndarray) -> np.ndarray:
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        elif img.shape[2] == 4:
            img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
        if img.dtype != np.uint8:
            img = cv2.convertScaleAbs(img, alpha=255.0 / max(float(img.max()), 1.0))
        if (img.shape[1], img.shape[0]) != (self._cfg.width, self._cfg.height):
            # intrinsics are for the configured size; a different stream size would break H
            img = cv2.resize(img, (self._cfg.width, self._cfg.height), interpolation=cv2.INTER_AREA)
        return img
