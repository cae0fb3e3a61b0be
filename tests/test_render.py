"""Renderer: determinism under seed, geometric exactness w.r.t. the camera homography, scene API."""

from __future__ import annotations

import numpy as np

from capm_field.camera import PinholeCamera, look_at
from capm_field.config import CameraConfig
from sim_bench.field_scene import FieldScene, Lighting
from sim_bench.plants import Part, Plant

CAM = PinholeCamera.from_config(CameraConfig(width=480, height=270, fx=375.0, fy=375.0))


def _T(x=1.0, y=1.0, h=0.9):
    return look_at(np.array([x + 0.25, y + 0.1, h]), np.array([x, y, 0.0]), np.array([1.0, 0.2, 0.0]))


def test_render_is_deterministic_under_seed() -> None:
    a = FieldScene.generate(5, weeds=[(1.0, 1.0, "rosette")], shadows=1).render(_T(), CAM)
    b = FieldScene.generate(5, weeds=[(1.0, 1.0, "rosette")], shadows=1).render(_T(), CAM)
    c = FieldScene.generate(6, weeds=[(1.0, 1.0, "rosette")], shadows=1).render(_T(), CAM)
    assert a.shape == (270, 480, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_ground_point_appears_where_the_homography_says() -> None:
    clean = Lighting(sun=(0.0, 0.0), vignette=0.0, noise_sigma=0.0)
    rng = np.random.default_rng(2)
    for k in range(6):
        X = rng.uniform(0.5, 1.5, 2)
        ang = np.linspace(0, 2 * np.pi, 60, endpoint=False)
        r = 0.01
        part = Part(X + r * np.c_[np.cos(ang), np.sin(ang)], X, X + [r, 0], (255.0, 0.0, 255.0), height=0.0)
        scene = FieldScene.generate(k, weeds=[], lighting=clean, clutter=False)
        scene.plants.append(Plant("marker", X, (part,), r))
        T = _T(*(X + rng.normal(0, 0.05, 2)), h=rng.uniform(0.5, 1.2))
        img = scene.render(T, CAM).astype(float)
        w = np.clip((img[..., 0] + img[..., 2]) / 2 - img[..., 1] - 60, 0, None)
        w = np.clip(w / (0.5 * w.max()), 0, 1)  # flat interior: the part's shading must not bias the centroid
        ys, xs = np.mgrid[0 : CAM.height, 0 : CAM.width]
        got = np.array([(w * xs).sum(), (w * ys).sum()]) / w.sum()
        want = CAM.ground_to_pixel(T, X[None])[0]
        # the centroid of a projected disc is off its projected centre by ~r²·tanθ/h (< 0.05 px here)
        assert np.linalg.norm(got - want) < 0.35


def test_scene_api_weeds_and_bare() -> None:
    s = FieldScene.generate(1, count=6, area=(0, 0, 3, 3))
    assert len(s.weeds) == 6
    for w in s.weeds:
        pts = np.concatenate([p.poly for p in w.plant.parts])
        assert np.linalg.norm(pts - w.troi_centre, axis=1).max() <= w.troi_radius + 1e-9
        assert w.kind in ("rosette", "seedling", "grass", "clover")
    assert FieldScene.bare(1).weeds == []


def test_sky_and_below_ground_poses_do_not_fail() -> None:
    s = FieldScene.generate(0, weeds=[(0.0, 0.0, "grass")])
    up = look_at(np.array([0, 0, 1.0]), np.array([3.0, 0, 1.2]))
    assert s.render(up, CAM).shape == (270, 480, 3)
    under = look_at(np.array([0, 0, -0.5]), np.array([0.5, 0, -1.0]))
    assert s.render(under, CAM).shape == (270, 480, 3)


def test_noise_windows_agree_seamlessly() -> None:
    """The fast noise is a function of the texel index: overlapping windows agree exactly."""
    from sim_bench.noise import fractal_grid

    F = [(3, 0.06, 0.002, 0.6), (2, 1.2, 0.15, 0.5), (9, 0.02, 0.001, 0.6)]
    a = fractal_grid(5, F, 768, -512, 256, 256, 0)
    b = fractal_grid(5, F, 1024, -512, 256, 256, 0)
    big = fractal_grid(5, F, 768, -512, 512, 256, 0)
    odd = fractal_grid(5, F, 768 + 17, -512 + 5, 100, 80, 0)
    assert np.array_equal(big[:, :256], a) and np.array_equal(big[:, 256:], b)
    assert np.array_equal(odd, a[5:85, 17:117])
    assert 0.5 < float(a[..., 0].std()) < 2.0  # a real texture, not constant


def test_tile_culling_does_not_change_the_image() -> None:
    """Tiles the warp never samples are skipped; the image is the same as with every tile built."""
    from sim_bench import field_scene as fs

    s1 = FieldScene.generate(4, weeds=[(1.0, 1.0, "clover")], shadows=1)
    s2 = FieldScene.generate(4, weeds=[(1.0, 1.0, "clover")], shadows=1)
    rng = np.random.default_rng(1)
    for k in range(3):
        T = _T(1.0 + rng.normal(0, 0.1), 1.0 + rng.normal(0, 0.1), h=rng.uniform(0.5, 1.3))
        a = s1.render(T, CAM)
        orig = fs._needed_tiles
        try:
            fs._needed_tiles = lambda camera, T, level, i0, j0, ni, nj: np.ones((nj, ni), bool)
            b = s2.render(T, CAM)
        finally:
            fs._needed_tiles = orig
        assert np.array_equal(a, b)
