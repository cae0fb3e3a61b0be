"""The hardware camera adapter (drivers/opencv_camera.py) on real OpenCV captures: image sequences
and an MJPG video written here, read by OpenCV's own backends (no device needed)."""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from capm_field.config import CameraConfig
from drivers.interfaces import DriverError, DriverTimeout
from drivers.opencv_camera import OpenCVCamera, fourcc_text

W, H = 160, 90  # a small 16:9 camera
CFG = CameraConfig(width=W, height=H, fx=150.0, fy=150.0)


def _scene(w: int, h: int) -> np.ndarray:
    """A frame with structure (gradients and a disc), so a wrong resize or channel order shows."""
    y, x = np.mgrid[0:h, 0:w]
    img = np.dstack([(x * 255 // max(w - 1, 1)), (y * 255 // max(h - 1, 1)), np.full_like(x, 90)]).astype(np.uint8)
    cv2.circle(img, (w // 3, h // 2), max(h // 5, 2), (20, 200, 40), -1)
    return img


def _sequence(tmp: Path, img: np.ndarray, n: int = 400) -> str:
    """An image-sequence source of `n` frames, all `img` (symlinks to one lossless PNG)."""
    tmp.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(tmp / "base.png"), img)
    for i in range(n):
        os.symlink("base.png", tmp / f"f_{i:04d}.png")
    return str(tmp / "f_%04d.png")


def test_frames_of_the_configured_size_arrive_unchanged(tmp_path):
    img = _scene(W, H)
    cam = OpenCVCamera(_sequence(tmp_path / "seq", img), CFG)
    try:
        f = cam.capture(5.0)
        assert f.image.dtype == np.uint8 and f.image.shape == (H, W, 3)
        assert np.array_equal(f.image, img)  # lossless source, no resize: bit for bit
        assert f.intrinsics.K[0, 0] == CFG.fx and (f.intrinsics.width, f.intrinsics.height) == (W, H)
        assert cam.stream_size == (W, H)
        g = cam.capture(5.0)
        assert g.stamp_ns > f.stamp_ns  # each capture waits for a newer frame
    finally:
        cam.close()


def test_a_larger_stream_of_the_same_aspect_is_resized_and_reported(tmp_path, caplog):
    big = _scene(2 * W, 2 * H)
    cam = OpenCVCamera(_sequence(tmp_path / "seq", big), CFG)
    try:
        with caplog.at_level(logging.WARNING, logger="drivers.opencv_camera"):
            f = cam.capture(5.0)
            cam.capture(5.0)
        assert f.image.shape == (H, W, 3)
        assert np.array_equal(f.image, cv2.resize(big, (W, H), interpolation=cv2.INTER_AREA))
        assert cam.stream_size == (2 * W, 2 * H)
        notes = [r.getMessage() for r in caplog.records if "resized" in r.getMessage()]
        assert len(notes) == 1 and f"{2 * W}x{2 * H}" in notes[0]  # once, not per frame
    finally:
        cam.close()


def test_a_stream_of_another_aspect_ratio_is_refused_not_stretched(tmp_path):
    cam = OpenCVCamera(_sequence(tmp_path / "seq", _scene(120, 90)), CFG)  # 4:3 for a 16:9 calibration
    try:
        with pytest.raises(DriverError, match=r"120x90.*aspect ratio.*robot\.camera"):
            cam.capture(5.0)
        with pytest.raises(DriverError):  # and stays refused
            cam.capture(0.5)
    finally:
        cam.close()


def test_the_end_of_a_stream_is_a_driver_error(tmp_path):
    cam = OpenCVCamera(_sequence(tmp_path / "seq", _scene(W, H), n=3), CFG)
    try:
        t0, err = time.monotonic(), None
        while err is None and time.monotonic() - t0 < 10:
            try:
                cam.capture(0.5)  # the sequence's frames may come first, or a wait may time out
            except DriverTimeout:
                continue
            except DriverError as e:
                err = e
        assert err is not None and "stream ended" in str(err)
        with pytest.raises(DriverError, match="stream ended"):  # and it stays ended
            cam.capture(0.1)
    finally:
        cam.close()


def test_a_source_that_cannot_be_opened(tmp_path):
    with pytest.raises(DriverError, match="cannot open camera"):
        OpenCVCamera(str(tmp_path / "missing_%04d.png"), CFG, open_timeout=1.0)


def test_capture_after_close_times_out_promptly(tmp_path):
    cam = OpenCVCamera(_sequence(tmp_path / "seq", _scene(W, H)), CFG)
    cam.close()
    cam.close()  # twice is fine
    t0 = time.monotonic()
    with pytest.raises((DriverTimeout, DriverError)):
        cam.capture(5.0)
    assert time.monotonic() - t0 < 1.0


def test_compressed_frames_and_an_unhonoured_format_are_reported(tmp_path, caplog):
    path = tmp_path / "clip.avi"
    wr = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, (W, H))
    assert wr.isOpened()
    for _ in range(200):
        wr.write(_scene(W, H))
    wr.release()
    cam = OpenCVCamera(str(path), CFG, fourcc="YUYV")  # a file cannot change its format
    try:
        assert cam.stream_format == "MJPG"
        with caplog.at_level(logging.WARNING, logger="drivers.opencv_camera"):
            f = cam.capture(5.0)
        msgs = " | ".join(r.getMessage() for r in caplog.records)
        assert "asked for YUYV" in msgs and "delivers MJPG" in msgs
        assert "compressed" in msgs and "fourcc: YUYV" in msgs
        assert f.image.shape == (H, W, 3)
    finally:
        cam.close()


def test_a_raw_stream_gives_no_format_warning(tmp_path, caplog):
    cam = OpenCVCamera(_sequence(tmp_path / "seq", _scene(W, H)), CFG)
    try:
        with caplog.at_level(logging.WARNING, logger="drivers.opencv_camera"):
            cam.capture(5.0)
        assert not caplog.records
    finally:
        cam.close()


@pytest.mark.parametrize("code, text", [(cv2.VideoWriter_fourcc(*"YUYV"), "YUYV"), (cv2.VideoWriter_fourcc(*"MJPG"), "MJPG"),
                                        (0, None), (-1, None), (float("nan"), None), (2**40, None)])
def test_fourcc_text(code, text):
    assert fourcc_text(code) == text


@pytest.mark.parametrize("value, ok", [("YUYV", True), ("MJPG", True), ("YUV", False), ("YUYV2", False), ("YU\nV", False),
                                       ("ÿUYV", False)])
def test_the_mission_file_checks_fourcc(value, ok):
    from pydantic import ValidationError

    from mission.config import CameraSpec

    if ok:
        assert CameraSpec(source=0, fourcc=value).fourcc == value
    else:
        with pytest.raises(ValidationError, match="FOURCC"):
            CameraSpec(source=0, fourcc=value)
