"""Heavy sensor noise (dim light, high gain): the noise estimate, the median filter of the index
image it switches on (`capm_field.search_window.DENOISE_FROM`), and frames of pure colour noise."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import capm_field.search_window as sw
from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig, TaskConfig
from capm_field.detector import detect_centre, ground_centre, roi_from_troi
from sim_bench.perception_bench import make_case

CAM = PinholeCamera.from_config(CameraConfig())


def _noisy(img: np.ndarray, sigma: float, seed: int) -> np.ndarray:
    return np.clip(img + np.random.default_rng(seed).normal(0, sigma, img.shape), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("sigma", [2.0, 5.0, 8.0, 12.0, 20.0])
def test_chroma_noise_measures_colour_noise_not_luminance_noise(sigma: float) -> None:
    """On a smooth textured scene with hard edges: Gaussian noise of σ independent in each channel is
    measured within 12 % + 0.6 grey levels; the same noise equal in all channels (luminance noise,
    which the vegetation index cancels) measures < 1.5, as does the scene alone."""
    rng = np.random.default_rng(int(sigma))
    scene = np.clip(cv2.GaussianBlur(rng.normal(110, 60, (480, 640, 3)), (0, 0), 4), 0, 255)
    cv2.rectangle(scene, (100, 100), (300, 260), (30, 160, 60), -1)  # hard edges
    clean = scene.astype(np.uint8)
    assert sw.chroma_noise(clean) < 1.5
    est = sw.chroma_noise(_noisy(clean, sigma, 1))
    assert abs(est - sigma) < 0.12 * sigma + 0.6, est
    grey = np.random.default_rng(2).normal(0, sigma, clean.shape[:2])[..., None]
    assert sw.chroma_noise(np.clip(clean + grey, 0, 255).astype(np.uint8)) < 1.5


def _bench(seed: int, i: int, bare: bool):
    case = make_case(seed, i, CAM, TaskConfig().delta, bare)
    return case, case.scene.render(case.T, CAM), roi_from_troi(CAM, case.T, case.troi_centre, case.troi_radius)


def test_noisy_bare_soil_is_no_plant_once_the_index_is_median_filtered(monkeypatch) -> None:
    """Bench bare-soil views (seed 21, 24 frames) under Gaussian noise σ = 15 in every channel:
    max-pooled, the noisy soil's index had specks as green as a seedling (4 frames answered a plant
    with the filter off, measured); with it, none (≤ 1 allowed)."""
    frames = [_bench(21, i, True) for i in range(24)]
    noisy = [(_noisy(img, 15, i), roi) for i, (_, img, roi) in enumerate(frames)]
    dbg: dict = {}
    detect_centre(frames[0][1], frames[0][2], debug=dbg)
    assert dbg["noise"] < sw.DENOISE_FROM  # as rendered: not filtered
    detect_centre(*noisy[0], debug=dbg)
    assert dbg["noise"] > sw.DENOISE_FROM  # σ = 15 ÷ the resampling factor (~11 here): filtered
    with_filter = sum(detect_centre(img, roi).reason not in ("no_plant", "bad_image") for img, roi in noisy)
    monkeypatch.setattr(sw, "DENOISE_FROM", float("inf"))
    without = sum(detect_centre(img, roi).reason not in ("no_plant", "bad_image") for img, roi in noisy)
    assert with_filter <= 1 and without >= 3, (with_filter, without)


def test_weeds_under_heavy_noise_are_still_found() -> None:
    """Bench weed views (seed 21, the first 16: four of each kind) under σ = 12 in every channel:
    the weed found within 30 mm in ≥ 13 (measured 14; as rendered 15, one clover missed). A guard
    that the filter does not erase weeds (it passes with the filter off too: the filter's gain is
    on bare soil, the test above)."""
    ok = 0
    for i in range(16):
        case, img, roi = _bench(21, i, False)
        det = detect_centre(_noisy(img, 12, i), roi)
        g = ground_centre(CAM, case.T, det)
        ok += g is not None and float(np.linalg.norm(g - case.scene.weeds[0].centre)) < 0.030
    assert ok >= 13, ok


def test_a_frame_of_colour_noise_is_a_bad_image_with_any_roi() -> None:
    """±45 levels of uniform noise in each channel round mid-grey: its grey level's pixel noise
    (~18) stays under NOISE_SIGMA, so only the grey level was asked and small ROIs answered a
    "plant" (confidence up to 1.0); its colour noise (~27) makes it noise."""
    img = np.random.default_rng(0).integers(45, 136, (720, 1280, 3)).astype(np.uint8)
    assert sw._pixel_noise(img) < sw.NOISE_SIGMA <= sw.chroma_noise(img)
    for roi in (None, (640, 360, 60), (640, 360, 100), (640, 360, 300)):
        assert detect_centre(img, roi).reason == "bad_image", roi


def test_the_noise_estimate_is_safe_on_tiny_windows() -> None:
    """Windows too small for a second difference give 0, never raise."""
    for shape in [(1, 1, 3), (4, 2, 3), (2, 200, 3), (300, 3, 3)]:
        assert sw.chroma_noise(np.zeros(shape, np.uint8)) == 0.0
