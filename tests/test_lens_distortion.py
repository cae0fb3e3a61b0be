"""Lens distortion (capm_field/lens.py): raw pixels ↔ field through OpenCV's model, checked against
OpenCV's own projection, the renderer and the detector; coefficients that fold are refused."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from pydantic import ValidationError

from capm_field.camera import PinholeCamera, look_at
from capm_field.config import CameraConfig
from capm_field.detector import detect_centre, ground_centre, roi_from_troi
from sim_bench.field_scene import FieldScene, Lighting
from sim_bench.plants import Part, Plant

BARREL = (-0.3, 0.1, 0.0005, -0.0008, -0.02)  # a wide-angle lens, as cv2.calibrateCamera reports one
PINCUSHION = (0.15, 0.05, 0.0, 0.0, 0.0)
RATIONAL = (-0.3, 0.1, 0.0, 0.0, 0.0, 0.01, 0.02, 0.0)
CLEAN = Lighting(exposure=1.0, white_balance=(1.0, 1.0, 1.0), sun=(0.0, 0.0), vignette=0.0, noise_sigma=0.0)


def _small(dist) -> PinholeCamera:
    return PinholeCamera.from_config(CameraConfig(width=480, height=270, fx=375.0, fy=375.0, distortion=dist))


def _oblique(rng: np.random.Generator) -> np.ndarray:
    aim = rng.uniform(-1, 1, 2)
    pos = np.r_[aim + rng.normal(0, 0.3, 2), rng.uniform(0.5, 1.3)]
    return look_at(pos, np.r_[aim, 0.0], np.r_[rng.normal(0, 1, 2), 0.0])


@pytest.mark.parametrize("dist", [BARREL, PINCUSHION, RATIONAL])
def test_pixel_field_pixel_round_trip_through_the_lens(dist) -> None:
    cam = PinholeCamera.from_config(CameraConfig(distortion=dist))
    rng = np.random.default_rng(0)
    worst, n = 0.0, 0
    for _ in range(100):
        T = _oblique(rng)
        uv = np.c_[rng.uniform(-0.5, cam.width - 0.5, 40), rng.uniform(-0.5, cam.height - 0.5, 40)]
        g = cam.pixel_to_ground(T, uv)
        ok = np.isfinite(g).all(axis=1)
        worst = max(worst, float(np.abs(cam.ground_to_pixel(T, g[ok]) - uv[ok]).max()))
        n += int(ok.sum())
    assert n > 3000 and worst < 0.1


@pytest.mark.parametrize("dist", [BARREL, PINCUSHION, RATIONAL])
def test_ground_to_pixel_is_opencvs_projection(dist) -> None:
    """An independent reference: cv2.projectPoints of the 3-D ground point with the pose's rvec, tvec."""
    cam = PinholeCamera.from_config(CameraConfig(distortion=dist))
    rng = np.random.default_rng(1)
    for _ in range(20):
        T = _oblique(rng)
        uv = np.c_[rng.uniform(0, cam.width, 30), rng.uniform(0, cam.height, 30)]
        X = cam.pixel_to_ground(T, uv)
        X = X[np.isfinite(X).all(axis=1)]
        R_cf = T[:3, :3].T
        rvec, _ = cv2.Rodrigues(R_cf)
        ref = cv2.projectPoints(np.c_[X, np.zeros(len(X))], rvec, -R_cf @ T[:3, 3], cam.K, np.asarray(dist, float))[0].reshape(-1, 2)
        assert np.abs(cam.ground_to_pixel(T, X) - ref).max() < 1e-6


def _marker(X: np.ndarray, seed: int, r: float = 0.006) -> FieldScene:
    ang = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    part = Part(X + r * np.c_[np.cos(ang), np.sin(ang)], X, X + [r, 0], (255.0, 0.0, 255.0), height=0.0)
    scene = FieldScene.generate(seed, weeds=[], lighting=CLEAN, clutter=False)
    scene.plants.append(Plant("marker", X, (part,), r))
    return scene


def _magenta(img: np.ndarray) -> np.ndarray:
    b, g, r = (img[..., i].astype(int) for i in range(3))
    return (b > 180) & (r > 180) & (g < 90)


@pytest.mark.parametrize("dist", [BARREL, PINCUSHION])
def test_rendered_ground_point_lands_where_the_lens_says(dist) -> None:
    """The bench renders through the lens: a marker near the frame's edge lies at ground_to_pixel
    (and far from where the ideal pinhole camera would put it)."""
    cam, ideal = _small(dist), _small(())
    rng = np.random.default_rng(2)
    T = look_at(np.array([1.25, 1.1, 0.9]), np.array([1.0, 1.0, 0.0]), np.array([1.0, 0.2, 0.0]))
    for k in range(4):
        uv = np.array([[rng.uniform(25, 90) if k % 2 else rng.uniform(390, 455), rng.uniform(25, 245)]])
        X = cam.pixel_to_ground(T, uv)[0]
        img = _marker(X, k).render(T, cam).astype(float)
        w = np.clip((img[..., 0] + img[..., 2]) / 2 - img[..., 1] - 60, 0, None)
        w = np.clip(w / (0.5 * w.max()), 0, 1)
        ys, xs = np.mgrid[0 : cam.height, 0 : cam.width]
        got = np.array([(w * xs).sum(), (w * ys).sum()]) / w.sum()
        assert np.linalg.norm(got - cam.ground_to_pixel(T, X[None])[0]) < 0.35
        assert np.linalg.norm(got - ideal.ground_to_pixel(T, X[None])[0]) > 4.0


@pytest.mark.parametrize("dist", [BARREL, PINCUSHION])
def test_coverage_through_the_lens_never_claims_a_disc_the_frame_cuts(dist) -> None:
    """disc_view tests coverage in the ideal image against the rectangle the raw frame surely sees
    (`Lens.ideal_bounds`): whenever it says covered, the rendered disc is whole in the frame. The
    image rectangle itself would be wrong both ways: too much through a pincushion lens (it cuts
    discs it calls covered), too little through a barrel lens (it refuses discs the frame holds)."""
    cam = _small(dist)
    naive = PinholeCamera(cam.width, cam.height, cam.K)
    rng = np.random.default_rng(3)
    centre, radius = np.array([0.3, -0.2]), 0.2
    ang = np.linspace(0, 2 * np.pi, 180, endpoint=False)
    part = Part(centre + radius * np.c_[np.cos(ang), np.sin(ang)], centre, centre + [radius, 0], (255.0, 0.0, 255.0), height=0.0)
    scene = FieldScene.generate(3, weeds=[], lighting=CLEAN, clutter=False)
    scene.plants.append(Plant("marker", centre, (part,), radius))
    covered = cut = naive_wrong = 0
    areas: list[tuple[float, float]] = []
    ys, xs = np.mgrid[0 : cam.height, 0 : cam.width]
    for _ in range(250):
        h = rng.uniform(0.85, 1.1)
        aim = centre - rng.choice([-1.0, 1.0], 2) * rng.uniform(0.3, 0.8, 2) * [0.4, 0.2]  # near the edges
        T = look_at(np.r_[aim + rng.normal(0, 0.03, 2), h], np.r_[aim, 0.0], np.array([1.0, rng.normal(0, 0.05), 0.0]))
        cov, ratio = (bool(v) if v.dtype == bool else float(v) for v in cam.disc_view(T, centre, radius, margin_px=1.5))
        cov_naive_in = bool(naive.disc_view(T, centre, radius, margin_px=1.5)[0])
        cov_naive_out = bool(naive.disc_view(T, centre, radius, margin_px=-1.5)[0])
        if not (cov or cov_naive_in or cov_naive_out):
            continue
        m = _magenta(scene.render(T, cam))
        whole = m.any() and not (m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any())
        covered += cov
        cut += cov and not whole
        if cov and len(areas) < 12:  # h = Area(R^TROI_I)/(u_max·v_max) counts raw pixels: those seeing the disc
            g = cam.pixel_to_ground(T, np.c_[xs.ravel(), ys.ravel()])
            areas.append((np.count_nonzero(np.linalg.norm(g - centre, axis=1) <= radius) / cam.image_area, ratio))
        naive_wrong += (cov_naive_in and not whole) or (not cov_naive_out and whole)
    assert covered >= 10 and cut == 0
    assert naive_wrong >= 4
    seen, said = np.array(areas).T
    assert len(areas) >= 10 and np.abs(said / seen - 1).max() < 0.01


def test_ideal_bounds_follow_the_lens() -> None:
    """Barrel distortion lets the raw frame see beyond the ideal image's rectangle, pincushion less."""
    w, h = 480, 270
    assert _small(()).lens.ideal_bounds == (-0.5, -0.5, w - 0.5, h - 0.5)
    lo_u, lo_v, hi_u, hi_v = _small(BARREL).lens.ideal_bounds
    assert lo_u < -0.5 and lo_v < -0.5 and hi_u > w - 0.5 and hi_v > h - 0.5
    lo_u, lo_v, hi_u, hi_v = _small(PINCUSHION).lens.ideal_bounds
    assert lo_u > -0.5 and lo_v > -0.5 and hi_u < w - 0.5 and hi_v < h - 0.5


def test_roi_through_the_lens_follows_the_discs_raw_image() -> None:
    cam = PinholeCamera.from_config(CameraConfig(distortion=BARREL))
    T = look_at(np.array([0.35, 0.2, 0.8]), np.array([0.3, 0.15, 0.0]), np.array([1.0, 0.0, 0.0]))
    Xw, r = np.array([0.62, 0.3]), 0.1
    roi = roi_from_troi(cam, T, Xw, r)
    a = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    inner = cam.ground_to_pixel(T, Xw + 0.97 * r * np.c_[np.cos(a), np.sin(a)])
    outer = cam.ground_to_pixel(T, Xw + 1.03 * r * np.c_[np.cos(a), np.sin(a)])
    assert roi.contains(inner).all() and not roi.contains(outer).any()
    # the ideal conic (no lens) misses the rim by pixels here
    ideal_roi = roi_from_troi(PinholeCamera(cam.width, cam.height, cam.K), T, Xw, r)
    assert not ideal_roi.contains(inner).all() or ideal_roi.contains(outer).any()
    d, _ = roi.on_ground(cam.ground_to_pixel(T, (Xw + [0.5 * r, 0.0])[None])[0])
    assert d == pytest.approx(0.5, abs=0.02)


@pytest.mark.parametrize("kind", ["rosette", "seedling"])
def test_a_weed_seen_through_the_lens_is_found_where_it_grows(kind) -> None:
    """Rendered through a barrel lens near the frame's corner, detected in the raw frame, mapped
    back through the lens: within 10 mm of its centre; ignoring the lens puts it > 15 mm off."""
    cam = PinholeCamera.from_config(CameraConfig(distortion=BARREL))
    ideal = PinholeCamera(cam.width, cam.height, cam.K)
    W = np.array([1.0, 1.0])
    size = 0.05 if kind == "rosette" else 0.03
    scene = FieldScene.generate(
        10, weeds=[dict(x=W[0], y=W[1], kind=kind, size=size, troi_centre=W, troi_radius=0.06)], distractors_per_m2=0.0
    )
    aim = W - np.array([0.33, 0.17])
    T = look_at(np.r_[aim, 0.75], np.r_[aim, 0.0], np.array([0.0, 1.0, 0.0]))
    det = detect_centre(scene.render(T, cam), roi_from_troi(cam, T, W, 0.06))
    assert det.pixel is not None, det.reason
    truth = scene.weeds[0].centre
    assert np.linalg.norm(ground_centre(cam, T, det) - truth) < 0.010
    assert np.linalg.norm(ideal.pixel_to_ground(T, np.array([det.pixel]))[0] - truth) > 0.015


@pytest.mark.parametrize(
    "dist, words",
    [
        ((0.1, 0.2, 0.3), "give 4, 5 or 8"),
        ((-0.9, 0.0, 0.0, 0.0), "does not invert"),
        ((0.0, 0.0, 0.3, 0.0), "does not invert"),
        ((1e5, 0.0, 0.0, 0.0), "no lens calibration"),
    ],
)
def test_a_distortion_that_folds_or_is_malformed_is_refused(dist, words) -> None:
    with pytest.raises(ValidationError, match=words):
        CameraConfig(distortion=dist)


def test_zero_distortion_is_the_pinhole_camera() -> None:
    plain = PinholeCamera.from_config(CameraConfig())
    zeros = PinholeCamera.from_config(CameraConfig(distortion=(0.0,) * 5))
    assert not zeros.distorted
    T = look_at(np.array([0.2, 0.1, 0.9]), np.array([0.0, 0.0, 0.0]))
    uv = np.array([[3.0, 4.0], [640.0, 360.0], [1270.0, 710.0]])
    assert np.array_equal(plain.pixel_to_ground(T, uv), zeros.pixel_to_ground(T, uv))


def test_a_mission_names_the_lens_key_it_refuses(tmp_path) -> None:
    from mission.config import MissionError, load_mission

    base = "name: m\nfield:\n  trois: [{x: 1.0, y: 1.0, r: 0.2}]\nrobot:\n  camera: {distortion: %s}\nstart: {x: 0, y: 0}\ndrivers: {kind: bench}\n"
    p = tmp_path / "m.yaml"
    p.write_text(base % "[-0.25, 0.08, 0.0005, -0.0008, -0.01]")
    mission, _ = load_mission(p)
    assert PinholeCamera.from_config(mission.robot.camera).distorted
    p.write_text(base % "[-0.9, 0, 0, 0]")
    with pytest.raises(MissionError, match=r"m\.yaml:5: robot\.camera: distortion .* does not invert"):
        load_mission(p)
