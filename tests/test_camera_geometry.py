"""Camera geometry: pixel ↔ field round trip, and NSV coverage (disc_view) vs what the renderer shows."""

from __future__ import annotations

import numpy as np
import pytest

from capm_field.camera import PinholeCamera, inv3
from capm_field.config import CameraConfig
from sim_bench.field_scene import FieldScene, Lighting
from sim_bench.perception_bench import pose_from_axis
from sim_bench.plants import Part, Plant

CAM = PinholeCamera.from_config(CameraConfig())
SMALL = PinholeCamera.from_config(CameraConfig(width=320, height=180, fx=250.0, fy=250.0))
CLEAN = Lighting(exposure=1.0, white_balance=(1.0, 1.0, 1.0), sun=(0.0, 0.0), vignette=0.0, noise_sigma=0.0)


def _random_pose(rng: np.random.Generator, target: np.ndarray, max_tilt: float = 35.0) -> np.ndarray:
    h = rng.uniform(0.5, 1.5)
    tilt = np.radians(rng.uniform(0, max_tilt))
    az = rng.uniform(0, 2 * np.pi)
    z = np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), -np.cos(tilt)])
    aim = np.r_[target + rng.normal(0, 0.25, 2), 0.0]
    return pose_from_axis(aim - z * h / np.cos(tilt), z, rng.uniform(0, 2 * np.pi))


def test_pixel_field_pixel_round_trip() -> None:
    rng = np.random.default_rng(0)
    worst = 0.0
    for _ in range(200):
        T = _random_pose(rng, rng.uniform(-2, 2, 2), max_tilt=60)
        uv = np.c_[rng.uniform(-0.5, CAM.width - 0.5, 50), rng.uniform(-0.5, CAM.height - 0.5, 50)]
        g = CAM.pixel_to_ground(T, uv)
        ok = np.isfinite(g).all(axis=1)
        back = CAM.ground_to_pixel(T, g[ok])
        worst = max(worst, float(np.abs(back - uv[ok]).max()))
    assert worst < 0.1


def _marker_scene(centre: np.ndarray, radius: float) -> FieldScene:
    ang = np.linspace(0, 2 * np.pi, 180, endpoint=False)
    poly = centre + radius * np.c_[np.cos(ang), np.sin(ang)]
    part = Part(poly, centre - [radius, 0], centre + [radius, 0], (255.0, 0.0, 255.0), height=0.0)
    scene = FieldScene.generate(3, weeds=[], lighting=CLEAN, clutter=False)
    scene.plants.append(Plant("marker", centre, (part,), radius))
    return scene


def _magenta(img: np.ndarray) -> np.ndarray:
    b, g, r = (img[..., i].astype(int) for i in range(3))
    return (b > 180) & (r > 180) & (g < 90)


def test_disc_view_coverage_matches_rendered_disc() -> None:
    """coverage True ⇔ the whole rendered TROI disc is inside the frame (poses near the edge skipped)."""
    rng = np.random.default_rng(1)
    centre, radius = np.array([0.3, -0.2]), 0.2
    scene = _marker_scene(centre, radius)
    checked = {True: 0, False: 0}
    for _ in range(120):
        T = _random_pose(rng, centre)
        cov_in, _ = SMALL.disc_view(T, centre, radius, margin_px=-1.5)
        cov_out, ratio = SMALL.disc_view(T, centre, radius, margin_px=1.5)
        if bool(cov_in) != bool(cov_out) or ratio <= 0:
            continue  # ellipse within 1.5 px of the border: anti-aliasing decides
        cov = bool(cov_out)
        m = _magenta(scene.render(T, SMALL))
        border = m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any()
        area = m.sum() / SMALL.image_area
        if cov:
            assert not border
            assert area == pytest.approx(float(ratio), rel=0.05)
        else:
            assert border or m.sum() == 0
        checked[cov] += 1
    assert checked[True] >= 10 and checked[False] >= 10


def test_inv3_is_numpys_inverse_and_marks_a_singular_matrix():
    """The adjugate inverse of the NSV conics (disc_conic, disc_view): numpy's inverse within
    rounding on well-conditioned stacks, and inf/nan, not an exception, for a singular one (a
    camera in the ground plane has a singular homography)."""
    rng = np.random.default_rng(3)
    m = rng.normal(size=(500, 3, 3)) + 3 * np.eye(3)
    np.testing.assert_allclose(inv3(m), np.linalg.inv(m), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(inv3(m[0]), np.linalg.inv(m[0]), rtol=1e-9, atol=1e-12)  # a single matrix too
    singular = np.array([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 1.0, 1.0]])
    assert not np.isfinite(inv3(singular)).all()
