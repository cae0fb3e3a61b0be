"""Lens distortion: OpenCV's camera model (Brown–Conrady radial and tangential terms, optionally
rational), as `cv2.calibrateCamera` estimates it and ROS names it (`plumb_bob`: k1, k2, p1, p2, k3;
`rational_polynomial`: + k4, k5, k6).

The planning core reasons on the ideal pinhole image (K, no distortion), where the ground plane
maps by the homography H(x_e) (camera.py). A real lens bends that image: a pixel the detector
finds in the raw frame is first moved to where the ideal camera would see the same ray
(`undistort`, OpenCV's iterative inversion), and an ideal pixel is bent back for the raw frame
(`distort`, OpenCV's model written out in numpy: `_bend`, tested against cv2.projectPoints).

A distortion polynomial is a valid lens model only where it is one-to-one: beyond the radius where
it folds back, far rays would land inside the image. `check` refuses coefficients that fold, or
fail to invert, anywhere over the image (a typo or the wrong calibration), and `Lens` treats ideal
points beyond the image's own field (`max_radius`) as seen by no pixel.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

LENGTHS = (0, 4, 5, 8)  # coefficient counts OpenCV and ROS use: none, k1 k2 p1 p2, + k3, + k4 k5 k6
ITERATIONS = 50  # of OpenCV's iterative inversion: 20 reach 1e-7 px at k1 = -0.35 (5, its default, 0.5 px)
ROUND_TRIP_PX = 0.01  # an inversion worse than this anywhere in the image is refused by `check`
FIELD_MARGIN = 1.05  # ideal points up to this × the image's own field radius still map to pixels


@dataclass(frozen=True)
class Lens:
    """Distortion coefficients `dist` for intrinsics K over a width × height image."""

    K: np.ndarray
    dist: np.ndarray
    width: int
    height: int

    @property
    def active(self) -> bool:
        return self.dist.size > 0 and bool(np.any(self.dist != 0.0))

    def undistort(self, uv: np.ndarray) -> np.ndarray:
        """Raw pixels (N, 2) → ideal pinhole pixels of the same rays (NaN stays NaN)."""
        uv = np.atleast_2d(np.asarray(uv, dtype=float))
        if not self.active:
            return uv.copy()
        out = np.full(uv.shape, np.nan)
        ok = np.isfinite(uv).all(axis=1)
        if ok.any():
            crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, ITERATIONS, 1e-14)
            src = np.ascontiguousarray(uv[ok]).reshape(-1, 1, 2)
            out[ok] = cv2.undistortPoints(src, self.K, self.dist, None, self.K, criteria=crit).reshape(-1, 2)
        return out

    def distort(self, uv_ideal: np.ndarray) -> np.ndarray:
        """Ideal pinhole pixels (N, 2) → raw pixels; NaN beyond the lens model's field (`max_radius`)."""
        uv = np.atleast_2d(np.asarray(uv_ideal, dtype=float))
        if not self.active:
            return uv.copy()
        xy = self._normalised(uv)
        with np.errstate(invalid="ignore"):
            far = ~(xy[:, 0] ** 2 + xy[:, 1] ** 2 <= (FIELD_MARGIN * self.max_radius) ** 2)  # NaN is far
        d = _bend(xy, self.dist)
        d[:, 0] = d[:, 0] * self.K[0, 0] + self.K[0, 2]
        d[:, 1] = d[:, 1] * self.K[1, 1] + self.K[1, 2]
        d[far] = np.nan
        return d

    def raw_area(self, conics: np.ndarray, n: int = 24) -> np.ndarray:
        """Raw-frame area (px²) of ideal-image ellipses given as conics (..., 3, 3): each rim sampled
        at n points, bent by the lens, measured by the shoelace formula (÷ the n-gon's share of its
        ellipse, exact without distortion; 24 points are within 0.02 % of 400 through k1 = -0.3); NaN
        where part of a rim maps to no pixel."""
        C = np.asarray(conics, dtype=float)
        M, b = C[..., :2, :2], C[..., :2, 2]
        c = -np.linalg.solve(M, b[..., None])[..., 0]  # centre
        k = np.einsum("...i,...ij,...j->...", c, M, c) - C[..., 2, 2]  # (p−c)ᵀM(p−c) = k on the rim
        lam, V = np.linalg.eigh(M)
        t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
        with np.errstate(invalid="ignore", divide="ignore"):
            ax = np.sqrt(k[..., None] / lam)  # semi-axes along V's columns
        circ = np.stack([np.cos(t), np.sin(t)])  # (2, n)
        rim = c[..., None, :] + np.swapaxes((V * ax[..., None, :]) @ circ, -1, -2)  # (..., n, 2)
        raw = self.distort(rim.reshape(-1, 2)).reshape(rim.shape)
        x, y = raw[..., 0], raw[..., 1]
        shoelace = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y, axis=-1))
        return shoelace / (n / (2.0 * np.pi) * np.sin(2.0 * np.pi / n))

    def _normalised(self, uv: np.ndarray) -> np.ndarray:
        return np.stack([(uv[:, 0] - self.K[0, 2]) / self.K[0, 0], (uv[:, 1] - self.K[1, 2]) / self.K[1, 1]], axis=1)

    def border(self, n: int = 64) -> np.ndarray:
        """The raw image's outer pixel edges (4n, 2), clockwise from the top-left corner."""
        w, h = self.width - 0.5, self.height - 0.5
        s = np.linspace(0.0, 1.0, n, endpoint=False)
        return np.concatenate(
            [
                np.c_[-0.5 + s * (w + 0.5), np.full(n, -0.5)],
                np.c_[np.full(n, w), -0.5 + s * (h + 0.5)],
                np.c_[w - s * (w + 0.5), np.full(n, h)],
                np.c_[np.full(n, -0.5), h - s * (h + 0.5)],
            ]
        )

    @cached_property
    def max_radius(self) -> float:
        """Largest normalised ideal radius any pixel of the image sees (its corners, usually)."""
        if not self.active:
            return float("inf")
        return float(np.max(np.hypot(*self._normalised(self.undistort(self.border())).T)))

    @cached_property
    def ideal_bounds(self) -> tuple[float, float, float, float]:
        """(u_lo, v_lo, u_hi, v_hi): an axis-aligned rectangle of the ideal image that every raw
        pixel edge encloses (the image rectangle itself without distortion). A region of the ideal
        image inside it is entirely in the raw frame; with barrel distortion the frame sees more,
        so coverage tested against this rectangle errs on the safe side."""
        w, h = self.width, self.height
        if not self.active:
            return (-0.5, -0.5, w - 0.5, h - 0.5)
        n = 256
        b = self.undistort(self.border(n))
        top, right, bottom, left = b[:n], b[n : 2 * n], b[2 * n : 3 * n], b[3 * n :]
        return (float(left[:, 0].max()), float(top[:, 1].max()), float(right[:, 0].min()), float(bottom[:, 1].min()))


def _bend(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """OpenCV's distortion of normalised points (N, 2), as cv2.projectPoints applies it (the same
    values to ~1e-13 px, tests/test_lens_distortion.py; 40× faster for a million points, which the
    raw areas of the reachability maps need): radial (k1, k2, k3 over k4, k5, k6) and tangential (p1, p2)."""
    k = np.zeros(8)
    k[: len(dist)] = dist
    k1, k2, p1, p2, k3, k4, k5, k6 = k
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    return np.stack([x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x), y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y], axis=1)


def check(K: np.ndarray, dist, width: int, height: int) -> str | None:
    """Why `dist` is no usable lens model over the image (None when it is): the raw → ideal inversion
    must reproduce every pixel within ROUND_TRIP_PX, and along every ray from the principal point the
    ideal radius must grow with the raw one, and the raw radius with the ideal one up to FIELD_MARGIN ×
    the image's field (else two directions share a pixel: the polynomial folds)."""
    lens = Lens(np.asarray(K, float), np.asarray(dist, float), int(width), int(height))
    if not lens.active:
        return None
    c = lens.K[:2, 2]
    ends = lens.border(90)
    t = np.linspace(0.0, 1.0, 97)[1:]
    raw = c + t[None, :, None] * (ends - c)[:, None, :]  # (rays, steps, 2)
    ideal = lens.undistort(raw.reshape(-1, 2))
    if not np.isfinite(ideal).all():
        return "cannot be inverted over the image"
    back = cv2.projectPoints(  # OpenCV's own projection here: the check does not trust _bend
        np.c_[lens._normalised(ideal), np.ones(len(ideal))], np.zeros(3), np.zeros(3), lens.K, lens.dist
    )[0].reshape(-1, 2)
    err = float(np.max(np.hypot(*(back - raw.reshape(-1, 2)).T)))
    if not err <= ROUND_TRIP_PX:
        return f"does not invert over the image (a pixel comes back {err:.3g} px off)"
    r_ideal = np.hypot(*lens._normalised(ideal).T).reshape(raw.shape[:2])
    if np.any(np.diff(r_ideal, axis=1) <= 0):
        return "folds inside the image (two rays reach one pixel)"
    # forward: the raw radius must keep growing over the ideal field (with a margin past the corners)
    xy = lens._normalised(ideal).reshape(raw.shape)[:, -1, :]  # the ideal point of each ray's end
    s = np.linspace(0.0, FIELD_MARGIN, 106)[1:]
    fwd = cv2.projectPoints(
        np.c_[(s[None, :, None] * xy[:, None, :]).reshape(-1, 2), np.ones(len(s) * len(xy))],
        np.zeros(3), np.zeros(3), np.eye(3), lens.dist,
    )[0].reshape(len(xy), len(s), 2)
    if np.any(np.diff(np.hypot(fwd[..., 0], fwd[..., 1]), axis=1) <= 0):
        return "folds just beyond the image's corners"
    return None
