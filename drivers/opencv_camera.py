"""Hardware camera over OpenCV: a device index, a URI (rtsp://, http://, file, an image sequence
such as `frames/%04d.png`) or a GStreamer pipeline string. Intrinsics come from CameraConfig
(calibrated values go in the mission file).

A reader thread keeps only the newest frame, so `capture()` returns a fresh image instead of a
stale one from the driver's buffer, and a hung device cannot block the caller past `timeout`.

The frames' pixel format matters to the weed-centre detector: on JPEG-compressed frames it gives
about twice the wrong centres (docs/perception.md §3). `fourcc` asks the device for a format (e.g.
"YUYV", uncompressed); a compressed stream, or a format the device did not honour, is reported at
the first capture (so the warning reaches the run log). Frames of another size are resized to the
configured one only if their aspect ratio is the same; otherwise the calibrated intrinsics would
not apply and every capture fails with a DriverError that says so.
"""

from __future__ import annotations

import logging
import threading
import time

import cv2
import numpy as np

from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig

from .interfaces import Camera, DriverError, DriverTimeout, Frame

log = logging.getLogger(__name__)

# Lossy stream formats (FOURCC codes as OpenCV reports them): the detector's figures on such frames
# are worse than on raw ones (docs/perception.md §3).
LOSSY_FOURCC = frozenset({"MJPG", "JPEG", "H264", "AVC1", "X264", "HEVC", "H265", "HVC1", "HEV1", "VP80",
                          "VP90", "AV01", "MP4V", "FMP4", "XVID", "DIVX"})
ASPECT_TOLERANCE = 0.01  # relative: a stream this far off the configured aspect ratio is refused


def fourcc_text(code: float | int) -> str | None:
    """OpenCV's CAP_PROP_FOURCC value as its four characters ("MJPG"), None if it is not one."""
    try:
        b = int(code).to_bytes(4, "little")
    except (ValueError, OverflowError):
        return None
    text = b.decode("ascii", "replace").rstrip("\0 ")
    return text if len(text) == 4 and text.isprintable() and "\ufffd" not in text else None


class OpenCVCamera(Camera):
    def __init__(self, source: int | str, config: CameraConfig | None = None, open_timeout: float = 5.0,
                 fourcc: str | None = None) -> None:
        self._cfg = config or CameraConfig()
        self._cam = PinholeCamera.from_config(self._cfg)
        self._source = source
        self._cond = threading.Condition()
        self._frame: np.ndarray | None = None
        self._stamp = 0
        self._seq = 0
        self._error: str | None = None
        self._stop = threading.Event()
        self._notes: list[str] = []  # warnings for the first capture (the run log is attached by then)
        self._stream_size: tuple[int, int] | None = None
        self._cap = self._open(source, open_timeout, fourcc)
        self.stream_format = fourcc_text(self._cap.get(cv2.CAP_PROP_FOURCC))
        """The stream's FOURCC as the device reports it ("YUYV", "MJPG"), None if it reports none."""
        if fourcc and self.stream_format != fourcc:
            self._notes.append(f"camera {source!r}: asked for {fourcc} frames, the device delivers "
                               f"{self.stream_format or 'an unreported format'}")
        if self.stream_format in LOSSY_FOURCC:
            self._notes.append(f"camera {source!r}: {self.stream_format} frames are compressed; the weed-centre "
                               "detector is measurably worse on them (docs/perception.md §3): ask for raw frames "
                               "(drivers.camera.fourcc: YUYV) if the camera offers them")
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
            notes, self._notes = self._notes, []
        for n in notes:
            log.warning(n)
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
    @property
    def stream_size(self) -> tuple[int, int] | None:
        """(width, height) of the frames the device delivers (before any resize), once one came."""
        return self._stream_size

    def _open(self, source: int | str, timeout: float, fourcc: str | None = None) -> cv2.VideoCapture:
        params = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, int(timeout * 1000), cv2.CAP_PROP_READ_TIMEOUT_MSEC, int(timeout * 1000)]
        if isinstance(source, str) and ("!" in source and "appsink" in source):
            cap = cv2.VideoCapture(source, cv2.CAP_GSTREAMER)
        else:
            cap = cv2.VideoCapture(source, cv2.CAP_ANY, params)
        if not cap.isOpened():
            cap.release()
            raise DriverError(f"cannot open camera {source!r}")
        if fourcc:  # before the size: V4L2 lists sizes per format
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*fourcc))
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
            if (img.shape[1], img.shape[0]) != self._stream_size and not self._check_size(img):
                return  # (checked again whenever the stream's size changes)
            img = self._to_bgr(img)
            with self._cond:
                self._frame, self._stamp = img, time.monotonic_ns()
                self._seq += 1
                self._cond.notify_all()

    def _check_size(self, img: np.ndarray) -> bool:
        """A frame of a new stream size against the configured size. False (and the error set) if
        the aspect ratio differs: the calibrated intrinsics would not apply to a stretched image."""
        h, w = img.shape[:2]
        cw, ch = self._cfg.width, self._cfg.height
        self._stream_size = (w, h)
        if h == 0 or abs((w / h) / (cw / ch) - 1.0) > ASPECT_TOLERANCE:
            with self._cond:
                self._error = (f"frames are {w}x{h}, not of the configured {cw}x{ch}'s aspect ratio: the "
                               "intrinsics (robot.camera) would not apply; set robot.camera to the stream's "
                               "size and calibration")
                self._cond.notify_all()
            return False
        if (w, h) != (cw, ch):
            with self._cond:
                self._notes.append(f"camera {self._source!r}: frames are {w}x{h}, resized to the configured {cw}x{ch} "
                                   "(robot.camera's intrinsics must be those of the resized image)")
        return True

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
