"""The search region of the weed-centre detector: the projected TROI R^TROI_I as an image conic.

`Roi` (conic, optional pixel → ground homography in TROI radii), `roi_from_troi` (from the camera
pose, X_w and r_w), `as_roi` (a Roi from what callers pass: a Roi, a 3×3 conic, an OpenCV ellipse,
a circle, a mask) and `roi_mask` (the grown ellipse rasterised on a detector grid).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Union

import cv2
import numpy as np

from .camera import PinholeCamera

ROI_MARGIN = 1.15  # leaves may overhang the TROI; the centre must lie inside it


MIN_SEMI_AXIS = 1e-3  # px: a ROI below a pixel holds nothing; below this its conic overflows


@dataclass(frozen=True)
class Roi:
    """Projected TROI R^TROI_I as an image conic: pixels p = (u, v, 1) with pᵀ·C·p ≤ 0 are inside.

    `conic` is normalised so the ellipse centre gives a negative value. `ellipse()` returns the
    same region as OpenCV's ((cu, cv), (full width, full height), angle in degrees).
    `ground`, when the camera pose is known (`roi_from_troi`): the homography pixel → ground point
    in TROI radii about the TROI centre (the TROI is the unit disc). With it the detector measures
    a candidate's distance from X_w and its area on the ground, not in the image: under an oblique
    view a plant's pixel area changes by up to ~1.7× across the ROI.
    """

    conic: np.ndarray
    ground: np.ndarray | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        """A ground map must be a homography that reaches the TROI centre (checked here, so a Roi
        built directly is held to it as well as one from `from_conic`)."""
        if self.ground is None:
            return
        g = np.asarray(self.ground, float).reshape(3, 3)
        if not np.all(np.isfinite(g)) or abs(np.linalg.det(g)) < 1e-300:
            raise ValueError("ground homography is singular")
        object.__setattr__(self, "ground", g)
        w0 = self._ground_w0  # LinAlgError (a ValueError) when numerically singular
        if not (math.isfinite(w0) and w0 != 0.0):
            raise ValueError("the ground homography does not reach the TROI centre")

    @classmethod
    def from_conic(cls, C: np.ndarray, ground: np.ndarray | None = None) -> "Roi":
        C = np.asarray(C, float).reshape(3, 3)
        C = 0.5 * (C + C.T)
        M = C[:2, :2]
        if not np.all(np.isfinite(C)) or np.linalg.det(M) <= 0:
            raise ValueError("conic is not a real ellipse")
        c = -np.linalg.solve(M, C[:2, 2])
        val = np.r_[c, 1.0] @ C @ np.r_[c, 1.0]
        if val == 0:
            raise ValueError("degenerate conic")
        if val > 0:
            C = -C
        if (np.r_[c, 1.0] @ C @ np.r_[c, 1.0]) >= 0:
            raise ValueError("conic has no interior")
        return cls(C, ground)

    @classmethod
    def from_ellipse(cls, centre: tuple[float, float], semi_axes: tuple[float, float], angle_deg: float = 0.0) -> "Roi":
        """Ellipse with centre (u, v), semi-axes (a, b) in pixels, a along `angle_deg` from the u axis."""
        a, b = float(semi_axes[0]), float(semi_axes[1])
        if not (a >= MIN_SEMI_AXIS and b >= MIN_SEMI_AXIS):  # 1/a² of 1e-300 px divided by zero
            raise ValueError(f"semi-axes must be at least {MIN_SEMI_AXIS:g} px")
        if not all(math.isfinite(v) for v in (a, b, float(angle_deg), *map(float, centre))):
            raise ValueError("ellipse must be finite")
        t = math.radians(angle_deg)
        R = np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
        M = R @ np.diag([1 / a**2, 1 / b**2]) @ R.T
        c = np.asarray(centre, float)
        C = np.zeros((3, 3))
        C[:2, :2] = M
        C[:2, 2] = C[2, :2] = -M @ c
        C[2, 2] = c @ M @ c - 1
        return cls(C)

    @classmethod
    def from_mask(cls, mask: np.ndarray) -> "Roi":
        """The ellipse with the centroid and second moments of a region mask (H×W or H×W×1, non-zero
        inside; e.g. the TROI disc rasterised by the caller): a filled ellipse gives itself back, any
        other region its equal-moment ellipse. Semi-axis 2·√(λ − 1/12) along each eigenvector of the
        pixels' covariance (λ: its eigenvalue; 1/12: a pixel's own spread). Raises ValueError for an
        empty or line-like mask, or one with NaN."""
        m = np.asarray(mask)
        if m.ndim == 3 and m.shape[2] == 1:
            m = m[:, :, 0]
        if m.ndim != 2 or m.dtype.kind not in "biuf":
            raise ValueError("a mask ROI is an H×W array of numbers")
        if m.dtype.kind == "f" and not np.all(np.isfinite(m)):
            raise ValueError("mask has NaN or infinite values")
        mo = cv2.moments(np.ascontiguousarray(m != 0).view(np.uint8), binaryImage=True)
        if mo["m00"] < 3:
            raise ValueError("mask is empty")
        cov = np.array([[mo["mu20"], mo["mu11"]], [mo["mu11"], mo["mu02"]]]) / mo["m00"]
        evals, evecs = np.linalg.eigh(cov)
        evals = evals - 1 / 12
        if not np.all(evals > 0.25):  # a semi-axis under 1 px: a line of pixels, no region
            raise ValueError("mask is a line, not a region")
        ang = math.degrees(math.atan2(evecs[1, 0], evecs[0, 0]))
        return cls.from_ellipse((mo["m10"] / mo["m00"], mo["m01"] / mo["m00"]), tuple(2 * np.sqrt(evals)), ang)

    def params(self) -> tuple[np.ndarray, np.ndarray, float]:
        """(centre (2,), semi-axes (2,), angle of the first axis in degrees)."""
        return self._params

    @functools.cached_property
    def _params(self) -> tuple[np.ndarray, np.ndarray, float]:
        # computed once per Roi (the detector asks ~8 times a frame; the conic is not changed)
        M = self.conic[:2, :2]
        c = -np.linalg.solve(M, self.conic[:2, 2])
        k = -(np.r_[c, 1.0] @ self.conic @ np.r_[c, 1.0])
        if not k > 0:
            raise ValueError("conic has no interior")
        evals, evecs = np.linalg.eigh(M / k)
        if not np.all(evals > 0):
            raise ValueError("conic has no interior")
        axes = 1 / np.sqrt(evals)
        ang = math.degrees(math.atan2(evecs[1, 0], evecs[0, 0]))
        return c, axes, ang

    def ellipse(self) -> tuple[tuple[float, float], tuple[float, float], float]:
        c, ax, ang = self.params()
        return (float(c[0]), float(c[1])), (float(2 * ax[0]), float(2 * ax[1])), ang

    def rim(self, n: int = 72) -> np.ndarray:
        """n pixels (n, 2) on the ellipse's rim, evenly in its parameter (for drawing it)."""
        c, ax, ang = self.params()
        t = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
        a = math.radians(ang)
        e = np.c_[ax[0] * np.cos(t), ax[1] * np.sin(t)]
        return c + e @ np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]])

    def on_ground(self, uv) -> tuple[float, float] | None:
        """For pixel uv: (distance from the TROI centre in TROI radii, ground area of a pixel there
        ÷ that at the TROI centre's image), from `ground`; None without it or off the ground."""
        if self.ground is None:
            return None
        q = self.ground @ np.array([float(uv[0]), float(uv[1]), 1.0])
        w0 = self._ground_w0
        if not (q[2] * w0 > 0):  # behind the camera or on the horizon
            return None
        # Jacobian of a homography: |det G| / w³, so the ratio to the centre's is (w0 / w)³
        return math.hypot(q[0] / q[2], q[1] / q[2]), float((w0 / q[2]) ** 3)

    @functools.cached_property
    def _ground_w0(self) -> float:
        p0 = np.linalg.solve(self.ground, np.array([0.0, 0.0, 1.0]))  # image of the TROI centre
        p0 = p0 / p0[2]
        return float(self.ground[2] @ p0)

    def contains(self, uv: np.ndarray, scale: float = 1.0) -> np.ndarray:
        """Whether pixels (N, 2) lie inside the ellipse grown about its centre by `scale`."""
        c, _, _ = self.params()
        uv = np.atleast_2d(np.asarray(uv, float))
        q = c + (uv - c) / scale
        C = self.conic
        u, v = q[:, 0], q[:, 1]
        return C[0, 0] * u * u + 2 * C[0, 1] * u * v + C[1, 1] * v * v + 2 * (C[0, 2] * u + C[1, 2] * v) + C[2, 2] <= 0


RoiLike = Union[Roi, np.ndarray, tuple, None]  # np.ndarray: a 3×3 conic or an H×W mask


def roi_from_troi(camera: PinholeCamera, T_field_cam: np.ndarray, centre_xy, radius: float) -> Roi:
    """R^TROI_I: the image of the TROI ground disc (centre X_w, radius r_w) seen from T_field_cam,
    with the pixel → ground map in TROI radii (`Roi.ground`). Through a distorting lens the disc's
    raw image is no exact ellipse: the Roi is then fitted to it (`_fitted_roi`)."""
    T = np.asarray(T_field_cam, float)
    if camera.distorted:
        fitted = _fitted_roi(camera, T, np.asarray(centre_xy, float).reshape(2), float(radius))
        if fitted is not None:
            return fitted
    C = camera.disc_conic(T, np.asarray(centre_xy, float), np.asarray(radius, float))
    x0, y0 = (float(v) for v in np.asarray(centre_xy, float).reshape(2))
    r = float(radius)
    N = np.array([[r, 0.0, x0], [0.0, r, y0], [0.0, 0.0, 1.0]])  # TROI radii → field
    try:
        ground = np.linalg.inv(camera.homography(T) @ N)
    except np.linalg.LinAlgError:  # a camera in the ground plane: the detector keeps pixel measures
        ground = None
    return Roi.from_conic(C, ground)


def _fitted_roi(camera: PinholeCamera, T: np.ndarray, centre_xy: np.ndarray, radius: float) -> Roi | None:
    """The Roi of a TROI disc seen through a distorting lens: the ellipse fitted (least squares,
    OpenCV) to the raw image of its rim, and the homography fitted to raw pixels of points across
    the disc (a local model of the pixel → ground map, in TROI radii). None when part of the disc
    maps to no pixel (then the ideal conic stands in)."""
    a = np.linspace(0.0, 2.0 * math.pi, 72, endpoint=False)
    rings = [(0.0, np.zeros(1))] + [(f, a[:: 72 // n]) for f, n in ((0.35, 12), (0.7, 24), (1.0, 72))]
    unit = np.concatenate([np.c_[f * np.cos(t), f * np.sin(t)] for f, t in rings])  # TROI radii
    uv = camera.ground_to_pixel(T, centre_xy + radius * unit)
    if not np.isfinite(uv).all():
        return None
    rim = uv[-72:].astype(np.float32)
    (cu, cv_), (w, h), ang = cv2.fitEllipse(rim)
    ground, _ = cv2.findHomography(uv, unit, 0)
    if ground is None or not (w > 0 and h > 0):
        return None
    C = Roi.from_ellipse((cu, cv_), (w / 2, h / 2), ang).conic
    try:
        return Roi.from_conic(C, ground)
    except ValueError:
        return None


def as_roi(roi: RoiLike, image_shape: tuple[int, ...] | None = None) -> Roi | None:
    """A `Roi` from a Roi, a 3×3 conic (array or nested lists), an OpenCV ellipse ((cu, cv),
    (width, height), angle in degrees), a circle ((cu, cv), radius) or (cu, cv, radius), or a
    mask of the image's size (`image_shape` (H, W), non-zero inside: `Roi.from_mask`; a mask
    covering the whole image is no ROI); None stays None. Raises ValueError if it is none of these."""
    if roi is None or isinstance(roi, Roi):
        return roi
    if isinstance(roi, np.ndarray) and roi.shape == (3, 3):
        return Roi.from_conic(roi)
    if isinstance(roi, np.ndarray) and roi.ndim in (2, 3):
        if image_shape is None or roi.shape[:2] != tuple(image_shape[:2]):
            raise ValueError(f"a mask ROI must be the image's size: {roi.shape[:2]} against {image_shape}")
        r = Roi.from_mask(roi)  # validates it
        return None if np.count_nonzero(roi) == roi.shape[0] * roi.shape[1] else r
    if isinstance(roi, (list, tuple)) and len(roi) == 3 and all(isinstance(r, (list, tuple, np.ndarray)) and len(r) == 3 for r in roi):
        return Roi.from_conic(np.asarray(roi, float))  # a conic as nested lists
    circle = _circle(roi)
    if circle is not None:
        cu, cv_, r = circle
        return Roi.from_ellipse((float(cu), float(cv_)), (float(r), float(r)))
    (cu, cv_), (w, h), ang = roi
    return Roi.from_ellipse((float(cu), float(cv_)), (float(w) / 2, float(h) / 2), float(ang))


def _circle(roi) -> tuple | None:
    """(cu, cv, radius) if `roi` is a circle as OpenCV gives one: (cu, cv, radius) from
    cv2.HoughCircles, or ((cu, cv), radius) from cv2.minEnclosingCircle; else None."""
    if not isinstance(roi, (list, tuple, np.ndarray)) or (isinstance(roi, np.ndarray) and roi.ndim != 1):
        return None
    if len(roi) == 3 and all(np.ndim(v) == 0 for v in roi):
        return tuple(roi)
    if len(roi) == 2 and np.shape(roi[0]) == (2,) and np.ndim(roi[1]) == 0:
        return (*roi[0], roi[1])
    return None


def roi_mask(roi: Roi, shape: tuple[int, int], x0: float, y0: float, sx: float, sy: float) -> np.ndarray:
    """The ROI ellipse grown by ROI_MARGIN, rasterised on a grid whose pixel (i, j) is the full
    image point (x0 + (j + ½)·sx − ½, y0 + (i + ½)·sy − ½)."""
    c, ax, ang = roi.params()
    t = math.radians(ang)
    # grid ← full: affine and axis-aligned scaling, so the ellipse maps to an ellipse exactly
    # unless sx ≠ sy (then approximately; both are within a pixel of each other)
    cg = ((c[0] - x0 + 0.5) / sx - 0.5, (c[1] - y0 + 0.5) / sy - 0.5)
    s_ = math.sqrt(sx * sy)
    S = 16
    if max(abs(cg[0]), abs(cg[1]), ROI_MARGIN * ax[0] / s_, ROI_MARGIN * ax[1] / s_) * S > 2**28:
        # beyond OpenCV's fixed-point drawing range (a far-off or huge ellipse): test each cell
        jj, ii = np.meshgrid(np.arange(shape[1]), np.arange(shape[0]))
        uv = np.c_[x0 + (jj.ravel() + 0.5) * sx - 0.5, y0 + (ii.ravel() + 0.5) * sy - 0.5]
        return roi.contains(uv, ROI_MARGIN).reshape(shape)
    m = np.zeros(shape, np.uint8)
    cv2.ellipse(m, (int(round(cg[0] * S)), int(round(cg[1] * S))),
                (max(1, int(round(ROI_MARGIN * ax[0] / s_ * S))), max(1, int(round(ROI_MARGIN * ax[1] / s_ * S)))),
                math.degrees(t), 0, 360, 1, -1, cv2.LINE_8, 4)
    return m.astype(bool)
