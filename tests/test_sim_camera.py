"""SimCamera: renders from the supplied pose; fault hooks drop or blacken the next frames."""

from __future__ import annotations

import numpy as np
import pytest

from capm_field.camera import look_at
from capm_field.config import CameraConfig
from capm_field.detector import detect_centre
from drivers.interfaces import DriverTimeout
from sim_bench.field_scene import FieldScene
from sim_bench.sim_camera import SimCamera


def test_sim_camera_frames_and_faults() -> None:
    scene = FieldScene.generate(2, weeds=[(0.0, 0.0, "rosette")])
    T = look_at(np.array([0.1, 0.0, 0.8]), np.array([0.0, 0.0, 0.0]))
    cam = SimCamera(scene, lambda: T, CameraConfig(width=320, height=180, fx=250.0, fy=250.0))
    f = cam.capture(1.0)
    assert f.image.shape == (180, 320, 3) and f.image.dtype == np.uint8
    assert np.allclose(f.camera_pose_field, T) and f.intrinsics.width == 320
    cam.inject_drop(1)
    with pytest.raises(DriverTimeout):
        cam.capture(0.01)
    cam.inject_black(2)
    for _ in range(2):
        black = cam.capture(1.0)
        assert black.image.max() == 0
        assert detect_centre(black.image).reason == "bad_image"
    assert cam.capture(1.0).image.max() > 0
    cam.close()
    cam.close()
