"""Weed-centre detector: the MPOI X̄_w (biological centre) of a plant in an arm-camera close-up.

Classical pipeline, no learned weights, sizes relative to the plant or the search window:
  1. validate the frame (dtype, shape, exposure, flatness) → reason "bad_image", never raise;
  2. stage 1, find the plant: the ROI window (projected TROI ellipse R^TROI_I grown by
     ROI_MARGIN) at ≤ WORK_PX; vegetation index G* = (G − max(R, B))/(R + G + B + 30) after a
     white balance that maps the soil to a typical soil colour, max-pooled so thin blades and
     stalks survive; threshold at soil + 5 σ with hysteresis; components whose own colour is
     not a plant's (stones, straw; anything not greener than magenta in the camera's own
     colours) dropped; the rest grouped into plants and scored by green
     area and centrality; none → "no_plant", a close runner-up → "ambiguous". Either answer,
     or a small (seedling-sized) first choice, gets a second look on CIELAB −a* (yellow-green
     leaves) that accepts vivid plants only;
  3. stage 2, find its centre: the chosen plant re-cut from the full-resolution frame at
     ~PLANT_PX across, centre from `capm_field.plant_centre` (stalk crossings, the tree median
     of geodesic distances to the leaf tips with leaf-axis votes, or the geometric median of
     plants whose leaf axes converge at many points), `capm_field.compound_leaf` (clover
     trefoils) or `capm_field.leaf_axes` (rosettes: where the leaves' axes meet);
  4. "cut_by_border" when the plant touches the frame edge near the centre; confidence.
The pixel returned follows the camera module's convention (pixel centres at integer coordinates);
`capm_field.camera.PinholeCamera.pixel_to_ground` maps it to the field (H⁻¹). Measured figures
and the reasons behind each threshold: docs/perception.md. The index images are made in
`capm_field.vegetation`, candidates are measured and judged in `capm_field.candidates`.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass, field
from typing import Literal, Union

import cv2
import numpy as np
from scipy import ndimage

from . import compound_leaf, leaf_axes, plant_centre, stalks
from .camera import PinholeCamera
from .candidates import (LC_RING, STRAW_ELONG, STRAW_ELONG_FULL, STRAW_RAW, candidate_features, contrast_band,
                         green_blade, plant_like)
from .components import components
from .order_stats import elongation, median, percentile
from .vegetation import downscale, pooled_index, resize_down, soil_gains, vegetation_index

log = logging.getLogger(__name__)

Reason = Literal["no_plant", "ambiguous", "cut_by_border", "bad_image"]

WORK_PX = 320  # stage 1 (find the plant): longest side of the search window after downscaling
PLANT_PX = 80  # stage 2 (find its centre): plant bounding box resampled to about this size
ROI_MARGIN = 1.15  # leaves may overhang the TROI; the centre must lie inside it


@dataclass(frozen=True)
class Detection:
    """Result of `detect_centre`.

    pixel: (u, v) of the biological centre when reason is None or "ambiguous" (best guess),
    else None. confidence in [0, 1]. reason: None on success, else "no_plant", "ambiguous",
    "cut_by_border" or "bad_image". Act on `pixel` only when `reason is None`.
    """

    pixel: tuple[float, float] | None
    confidence: float
    reason: Reason | None = None


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
        if ground is not None:
            ground = np.asarray(ground, float).reshape(3, 3)
            if not np.all(np.isfinite(ground)) or abs(np.linalg.det(ground)) < 1e-300:
                raise ValueError("ground homography is singular")
        return cls(C, ground)

    @classmethod
    def from_ellipse(cls, centre: tuple[float, float], semi_axes: tuple[float, float], angle_deg: float = 0.0) -> "Roi":
        """Ellipse with centre (u, v), semi-axes (a, b) in pixels, a along `angle_deg` from the u axis."""
        a, b = float(semi_axes[0]), float(semi_axes[1])
        if not (a > 0 and b > 0):
            raise ValueError("semi-axes must be positive")
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


RoiLike = Union[Roi, np.ndarray, tuple, None]


def roi_from_troi(camera: PinholeCamera, T_field_cam: np.ndarray, centre_xy, radius: float) -> Roi:
    """R^TROI_I: the image of the TROI ground disc (centre X_w, radius r_w) seen from T_field_cam,
    with the pixel → ground map in TROI radii (`Roi.ground`)."""
    T = np.asarray(T_field_cam, float)
    C = camera.disc_conic(T, np.asarray(centre_xy, float), np.asarray(radius, float))
    x0, y0 = (float(v) for v in np.asarray(centre_xy, float).reshape(2))
    r = float(radius)
    N = np.array([[r, 0.0, x0], [0.0, r, y0], [0.0, 0.0, 1.0]])  # TROI radii → field
    try:
        ground = np.linalg.inv(camera.homography(T) @ N)
    except np.linalg.LinAlgError:  # a camera in the ground plane: the detector keeps pixel measures
        ground = None
    return Roi.from_conic(C, ground)


def ground_centre(camera: PinholeCamera, T_field_cam: np.ndarray, det: Detection) -> np.ndarray | None:
    """MPOI X̄_w on the ground (x, y) from a detection, via H⁻¹; None without a pixel."""
    if det.pixel is None:
        return None
    g = camera.pixel_to_ground(T_field_cam, np.asarray(det.pixel, float)[None])[0]
    return g if np.all(np.isfinite(g)) else None


# ---- entry point --------------------------------------------------------------------------------
def detect_centre(image_bgr: np.ndarray, roi: RoiLike = None, debug: dict | None = None) -> Detection:
    """Find the biological centre of the main plant in a BGR uint8 image (never raises).

    roi: None (whole image), a `Roi`, a 3×3 image conic (pᵀCp ≤ 0 inside) or an OpenCV-style
    ellipse ((cu, cv), (width, height), angle_deg). A malformed roi gives "bad_image".
    """
    try:
        win = _window(image_bgr, roi)
        if isinstance(win, Detection):
            return win
        first: dict = {}
        det = _detect(image_bgr, roi, debug, first=first, win=win)
        if det.reason in ("no_plant", "ambiguous"):
            # second look on the green–red axis of CIELAB: yellow-green leaves (young seedlings,
            # chlorotic plants, warm light) reflect nearly as much red as green, so G − max(R, B)
            # leaves them at the soil's level; only vivid candidates count (soil tints come up too)
            # (also after an "ambiguous" first look: a pale plant split in two by G* is one in −a*)
            second: dict = {}
            det2 = _detect(image_bgr, roi, debug, vivid=True, first=second, win=win)
            if (det.reason == "ambiguous" and det2.reason is None and second["best"] <= SMALL_GAIN * first["best"]
                    and not _boxes_meet([second["box"]], first["contenders"])):
                # the second look chose something else than the plants in question, and nothing
                # clearly larger (a vivid speck) (a clover's centre lies between its leaflets'
                # boxes: the chosen plant's box must meet one, not hold the centre)
                return det
            if det2.reason is None or (det.reason == "no_plant" and det2.reason != "no_plant"):
                return det2
        elif det.reason is None and (first["best"] < SMALL_PLANT * win.n_in or first["feat"]["g_p90"] < PALE_G90
                                     or first["feat"]["gsig"] < FAINT_SIGMA):
            # a small first choice (seedling-sized) may be a vivid speck while the weed is a pale
            # seedling only the second look segments; a first choice of low absolute greenness may
            # be only the greenest part of a yellow-green plant, which −a* segments whole: take
            # the second look's choice when it scores clearly higher (bench seeds 0–3: wrong
            # 39 → 36, > 15 mm 110 → 106 for the small ones)
            # (the second look's plant is chosen first; its centre is sought only if it is taken.
            # Its debug entries join `debug` only then)
            dbg2: dict | None = {} if debug is not None else None
            second = {}
            choice = _choose(image_bgr, win, vivid=True, debug=dbg2, first=second)
            if isinstance(choice, _Choice) and (choice.best > SMALL_GAIN * first["best"] or (
                    # or the same plant, segmented far more completely (yellow-green parts, petioles)
                    second["feat"]["area"] >= WHOLE_GAIN * first["feat"]["area"]
                    and _boxes_meet([second["box"]], [first["box"]]))):
                det2 = _locate(image_bgr, win, choice, dbg2)
                if det2.reason is None:
                    if debug is not None and dbg2 is not None:
                        _merge_debug(debug, dbg2)
                    return det2
        return det
    except Exception:  # the contract is "never raise": a bug must not stop a mission ...
        # ... but it must not go unseen either: the traceback goes to the log (and so the run's)
        log.exception("weed-centre detector failed on a %s %s image; answering bad_image",
                      getattr(image_bgr, "shape", "?"), getattr(image_bgr, "dtype", type(image_bgr).__name__))
        return Detection(None, 0.0, "bad_image")


SMALL_PLANT = 0.003  # first choice's score / ROI pixels (stage-1 grid) below which the second look also runs
# (~25 % of the bench's weed frames, mostly seedlings; 0.01 measured 1 fewer wrong on seeds 0–3 but
# +5 ms median latency, 0.003 +1.7 ms; session 9, second look choosing before locating: 0.01 gave
# 3 fewer wrong and p90 −0.3 to −1.1 mm on seeds 0–3, +3 ms median (paired) — the −a* index alone
# costs ~4 ms a frame; not taken while the median is at the 20 ms target)
SMALL_GAIN = 1.5  # the second look's choice must score this × the first's to replace it ...
WHOLE_GAIN = 1.5  # ... or be the same plant (boxes meet) with this × its stage-1 area (bench seeds 0–3:
# wrong 20 → 18, 11 answers ≥ 2 mm better, 3 worse; 1.3, replayed offline: 16 better, 8 worse)
FAINT_SIGMA = 6.0  # first choice's G* p90 over the soil, in soil σ, below which the second look also runs: a
# blue-green plant on a reddish soil, whose white balance lifts blue, clears G*'s 5 σ in one leaf only
PALE_G90 = 0.05  # first choice's G* p90 below which the second look also runs (+8 % of the bench's
# frames; bench and photo-like benches: 6 answers ≥ 0.1 S better, 1 worse; always: +10 ms median)


def _merge_debug(debug: dict, extra: dict) -> None:
    """`extra`'s lists (components, candidates) appended to `debug`'s; its other entries replace them."""
    for k, v in extra.items():
        if isinstance(v, list):
            debug.setdefault(k, []).extend(v)
        else:
            debug[k] = v


def _boxes_meet(a: list, b: list) -> bool:
    """Whether a box (x0, y0, x1, y1) of `a` overlaps one of `b` (None: no box)."""
    return any(ax0 <= bx1 and bx0 <= ax1 and ay0 <= by1 and by0 <= ay1
               for ax0, ay0, ax1, ay1 in filter(None, a) for bx0, by0, bx1, by1 in filter(None, b))


def _as_roi(roi: RoiLike) -> Roi | None:
    if roi is None or isinstance(roi, Roi):
        return roi
    if isinstance(roi, np.ndarray) and roi.shape == (3, 3):
        return Roi.from_conic(roi)
    if isinstance(roi, (list, tuple)) and len(roi) == 3 and all(isinstance(r, (list, tuple, np.ndarray)) and len(r) == 3 for r in roi):
        return Roi.from_conic(np.asarray(roi, float))  # a conic as nested lists
    (cu, cv_), (w, h), ang = roi
    return Roi.from_ellipse((float(cu), float(cv_)), (float(w) / 2, float(h) / 2), float(ang))


@dataclass(frozen=True)
class _Window:
    """The search window of one frame and what both looks compute from it alone (made once per
    frame: the second look would repeat the two large area resamplings and the soil statistics).
    Arrays are shared between the looks and must not be modified."""

    roi: Roi | None
    x0: int  # window in the full image: [x0, x1) × [y0, y1)
    y0: int
    x1: int
    y1: int
    mid: np.ndarray  # the window at ≤ MID_PX_STAGE1 px (the index is computed on it)
    small: np.ndarray  # the window at ≤ WORK_PX on its longest side (stage-1 grid)
    sx: float  # window pixels per `small` pixel
    sy: float
    inside: np.ndarray  # ROI mask on the stage-1 grid
    n_in: int  # its pixel count
    gains: np.ndarray  # soil white balance of the first look (`soil_gains`)

    def to_full(self, p: np.ndarray) -> np.ndarray:
        """Stage-1 grid point (j, i) → full image (x0 + (j + ½)·sx − ½, y0 + (i + ½)·sy − ½)."""
        return np.array([self.x0 + (p[0] + 0.5) * self.sx - 0.5, self.y0 + (p[1] + 0.5) * self.sy - 0.5])


def _window(img: np.ndarray, roi_in: RoiLike) -> _Window | Detection:
    """Search window (ROI bounding box grown by the margin), its downscales, exposure check, ROI
    mask and soil white balance; Detection "bad_image" when the frame or roi is not usable."""
    bad = Detection(None, 0.0, "bad_image")
    if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        return bad
    H, W = img.shape[:2]
    if H < 16 or W < 16:
        return bad
    try:
        roi = _as_roi(roi_in)
        if roi is not None:
            c, ax, ang = roi.params()  # raises for a conic without interior
            # an ellipse holding all four corners holds the whole (convex) frame: no ROI then
            if bool(np.all(roi.contains(np.array([[0.0, 0.0], [W - 1.0, 0.0], [0.0, H - 1.0], [W - 1.0, H - 1.0]])))):
                roi = None
    except Exception:  # noqa: BLE001
        return bad

    # ---- search window (ROI bounding box grown by the margin) and stage-1 downscale
    if roi is not None:
        t = math.radians(ang)
        ex = ROI_MARGIN * math.hypot(ax[0] * math.cos(t), ax[1] * math.sin(t))
        ey = ROI_MARGIN * math.hypot(ax[0] * math.sin(t), ax[1] * math.cos(t))
        x0, y0 = max(int(math.floor(c[0] - ex)), 0), max(int(math.floor(c[1] - ey)), 0)
        x1, y1 = min(int(math.ceil(c[0] + ex)) + 1, W), min(int(math.ceil(c[1] + ey)) + 1, H)
        if x1 - x0 < 8 or y1 - y0 < 8:
            return bad
    else:
        x0, y0, x1, y1 = 0, 0, W, H
    crop = img[y0:y1, x0:x1]
    # the index image (≤ MID_PX_STAGE1 px, see pooled_index) is made once; the ≤ WORK_PX grid is
    # resampled from it rather than from the full window (one large area resampling, not two)
    mid = downscale(crop, MID_PX_STAGE1)
    s = max(1.0, max(crop.shape[:2]) / WORK_PX)
    if s > 1.0:
        small = resize_down(mid, (max(1, round(crop.shape[1] / s)), max(1, round(crop.shape[0] / s))))
    else:
        small = crop
    sx, sy = crop.shape[1] / small.shape[1], crop.shape[0] / small.shape[0]

    # ---- exposure sanity on the window
    gray = cv2.cvtColor(small, cv2.COLOR_BGR2GRAY)
    mean = float(cv2.mean(gray)[0])
    # flat = no variation in any channel (a green leaf can have the soil's grey level exactly)
    std = float(cv2.meanStdDev(small)[1].max())
    b_, g_, r_ = cv2.split(small)
    sat = float(np.count_nonzero(cv2.min(cv2.min(b_, g_), r_) >= 250)) / gray.size  # clipped to white
    # (flat: also no pixel off by FLAT_RANGE, which a plant of a few grid pixels is, however small)
    flat = std < 1.5 and int(np.ptp(small.reshape(-1, 3), axis=0).max()) < FLAT_RANGE
    if mean < 12 or sat > 0.6 or flat or mean > 245:
        return bad
    if _coherence(mid) < NOISE_COHERENCE and _pixel_noise(crop) >= NOISE_SIGMA:
        # strong noise, not a scene (a faulty sensor or a corrupted stream): max-pooled, it looks
        # green. Weak noise on a flat soil has no structure either, but a leaf as bright as the
        # soil is structure in colour only: such a frame is read, not rejected
        return bad

    inside = np.ones(gray.shape, bool)
    if roi is not None:
        inside = _roi_mask(roi, gray.shape, x0, y0, sx, sy)
    n_in = int(np.count_nonzero(inside))
    if roi is not None and n_in < 16:
        return bad
    return _Window(roi, x0, y0, x1, y1, mid, small, sx, sy, inside, n_in, soil_gains(small, inside))


FLAT_RANGE = 16  # grey levels: a blank frame under sensor noise σ ≤ 5 stays within it on the stage-1 grid
NOISE_COHERENCE = 0.65  # measured: bench, photo-like and other-renderer frames ≥ 0.87; RGB noise ≤ 0.56
NOISE_SIGMA = 24.0  # grey levels of pixel noise (`_pixel_noise`) from which an incoherent frame is noise:
# uniform RGB noise ≈ 50 (JPEG-compressed ≈ 51–54), Gaussian σ = 40 per channel ≈ 27, a flat soil under σ = 30 ≈ 20


def _pixel_noise(bgr: np.ndarray) -> float:
    """Pixel-scale noise σ of the grey level, in grey levels, from the mean absolute difference of
    horizontal neighbours on every 8th row (σ = E|d|·√π / 2 for Gaussian noise). Asked only of
    frames without structure, where the scene's edges add little."""
    g = cv2.cvtColor(np.ascontiguousarray(bgr[::8]), cv2.COLOR_BGR2GRAY).astype(np.int16)
    if g.shape[1] < 2:
        return 0.0
    return float(np.abs(np.diff(g, axis=1)).mean()) * math.sqrt(math.pi) / 2.0


def _coherence(bgr: np.ndarray) -> float:
    """Spread of the grey level after 2 × 2 averaging over its spread before: ≈ 0.5 for white
    noise (no spatial structure), ≈ 1 for a scene (structure larger than a pixel)."""
    g = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    h, w = (g.shape[0] // 2) * 2, (g.shape[1] // 2) * 2
    if h < 4 or w < 4:
        return 1.0
    s0 = float(cv2.meanStdDev(g[:h, :w])[1][0, 0])
    s2 = float(cv2.meanStdDev(cv2.resize(g[:h, :w], (w // 2, h // 2), interpolation=cv2.INTER_AREA))[1][0, 0])
    return s2 / s0 if s0 > 0 else 1.0


def _detect(img: np.ndarray, roi_in: RoiLike, debug: dict | None = None, vivid: bool = False,
            first: dict | None = None, win: _Window | None = None) -> Detection:
    """One look (G* or, with `vivid`, CIELAB −a*): the plant is chosen (`_choose`), then its
    centre is found (`_locate`). `first` receives the full-image boxes of the candidates within
    0.8 of the best score under "contenders" (those an "ambiguous" is about), the best score
    under "best" and the chosen candidate's features under "feat". `win`: the frame's
    `_window(img, roi_in)` when already made."""
    if win is None:
        win = _window(img, roi_in)
        if isinstance(win, Detection):
            return win
    choice = _choose(img, win, vivid, debug, first)
    return choice if isinstance(choice, Detection) else _locate(img, win, choice, debug)


@dataclass
class _Choice:
    """A look's plants, scored, before the centre of the best is sought (see `_choose`)."""

    vivid: bool
    gains: np.ndarray  # white balance of this look
    thr: float  # index threshold and soil level of this look
    soil_level: float
    contrast: float
    lab: np.ndarray  # component labels on the stage-1 grid
    scored: list  # (score, stage-1 mask, area, full-image box or None, features), best first

    @property
    def best(self) -> float:
        return self.scored[0][0]


def _choose(img: np.ndarray, win: _Window, vivid: bool = False, debug: dict | None = None,
            first: dict | None = None) -> _Choice | Detection:
    """Stage 1 of one look: the vegetation mask of the window, its candidate plants judged and
    scored (green mass × centrality). Detection "no_plant" when there is none; `first` as in
    `_detect`."""
    roi, x0, y0 = win.roi, win.x0, win.y0
    mid, small, sx, sy, inside, n_in = win.mid, win.small, win.sx, win.sy, win.inside, win.n_in

    to_full = win.to_full  # window pixel (i, j) of `small` → full image

    # ---- vegetation mask
    gains = win.gains ** VIVID_WB if vivid else win.gains
    vi = pooled_index(mid, gains, (small.shape[1], small.shape[0]), MID_PX_STAGE1, lab=vivid)
    # soil statistics from every other row and column: the same percentiles in a quarter of the time
    thr, soil_level, contrast = _threshold(vi[::2, ::2][inside[::2, ::2]] if n_in >= 4096 else vi[inside])
    mask = _hysteresis(vi, thr, soil_level, inside)
    n, lab, stats, cents = components(mask)
    min_area = max(6.0, 1.5e-4 * n_in)
    comps = [k for k in range(1, n) if stats[k, cv2.CC_STAT_AREA] >= min_area]
    if not comps:
        return Detection(None, 0.0, "no_plant")
    # soil spread of the index outside the vegetation mask (robust: median → p90)
    soil_px = vi[::2, ::2][(inside & ~mask)[::2, ::2]] if n_in >= 4096 else vi[inside & ~mask]
    sig = max((percentile(soil_px, 90) - soil_level) / 1.28, 1e-3) if soil_px.size >= 16 else 0.01
    # ROI centre and radius on the stage-1 grid (candidate centrality)
    if roi is not None:
        rc, rax, _ = roi.params()
        cen_s = np.array([(rc[0] - x0 + 0.5) / sx - 0.5, (rc[1] - y0 + 0.5) / sy - 0.5])
        rad_s = float(np.sqrt(rax[0] * rax[1]) / math.sqrt(sx * sy))
    else:
        cen_s = np.array([(small.shape[1] - 1) / 2, (small.shape[0] - 1) / 2])
        rad_s = 0.5 * math.hypot(*small.shape[:2])
    # components whose own colour is not a plant's (straw, stones) are not grouped with plants
    keep = []
    feats: dict[int, dict] = {}  # per component: also the features of a group of that one component

    def measure(m: np.ndarray, l0: int, t0: int) -> dict:  # features of a mask cropped from grid (l0, t0)
        h0, w0 = m.shape
        f = candidate_features(m, vi[t0:t0 + h0, l0:l0 + w0], small[t0:t0 + h0, l0:l0 + w0], gains, soil_level, sig,
                               cen_s, rad_s, origin=(l0, t0))
        f["area_frac"] = f["area"] / n_in
        return f

    for k in comps:
        l0, t0, w0, h0 = (int(v) for v in stats[k, :4])
        sub = lab[t0:t0 + h0, l0:l0 + w0] == k
        f = measure(sub, l0, t0)
        if vivid and contrast_band(f):
            f["lc"], f["core"] = _local_contrast(img, sub, (l0, t0), win, gains, thr, soil_level)
        ok = _kept(f, vivid)
        if not ok and not vivid and SPLIT_GREEN and stats[k, cv2.CC_STAT_AREA] >= SPLIT_MIN * min_area:
            # a plant touching a larger stone (or straw) that the white balance made as green: one
            # component, of the stone's median colour. Its green part alone, if that is clearly a
            # plant, stays as this component (first look only: in −a* the part taken from soil
            # tints and straw made distractor seedlings outscore the weed)
            part = _green_part(sub, small[t0:t0 + h0, l0:l0 + w0], min_area)
            f2 = measure(part, l0, t0) if part is not None else None
            if f2 is not None and _kept(f2, False) and _clearly_green(f2):
                lab[t0:t0 + h0, l0:l0 + w0][sub & ~part] = 0
                py, px = np.nonzero(part)
                stats[k, cv2.CC_STAT_AREA] = len(px)  # (its box stays: a superset, for grouping)
                cents[k] = (l0 + px.mean(), t0 + py.mean())
                f, ok = f2, True
        feats[k] = dict(f)
        if ok:
            keep.append(k)
        if debug is not None:  # every component's colour features and full-image centroid
            f.update(ok=ok, vivid=vivid, c=[float(v) for v in to_full(cents[k])])
            debug.setdefault("comps", []).append(f)
    comps = keep
    if not comps:
        return Detection(None, 0.0, "no_plant")

    # ---- plants: group components, score by size and centrality
    groups = _group(lab, stats, comps)
    rim = inside & ~cv2.erode(inside.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) if roi is not None else np.zeros_like(inside)
    scored = []
    for g in groups:
        if debug is None and int(stats[g, cv2.CC_STAT_AREA].sum()) < (VIVID_AREA if vivid else 1.5) * min_area:
            continue  # too small to be chosen: no features needed
        if len(g) == 1:  # the component's own features (same pixels in the same order: same values)
            gm = lab == g[0]
            f = dict(feats[g[0]])
        else:
            gm = np.isin(lab, g)
            f = candidate_features(gm, vi, small, gains, soil_level, sig, cen_s, rad_s)
            if vivid and contrast_band(f):
                gy, gx = np.nonzero(gm)
                bx, by = int(gx.min()), int(gy.min())
                f["lc"], f["core"] = _local_contrast(img, gm[by:gy.max() + 1, bx:gx.max() + 1], (bx, by), win, gains, thr, soil_level)
        f["area_frac"] = f["area"] / n_in
        box = None  # full-image box of a candidate with a positive score, for "contenders"
        f["ok"] = bool(f["area"] >= (VIVID_AREA if vivid else 1.5) * min_area and plant_like(f, vivid)
                       and (f["elong"] <= STRAW_ELONG or green_blade(f)))
        if f["ok"]:
            # green mass measured at full resolution (the stage-1 max-pooling inflates small
            # objects), × a mild pull towards the TROI centre (the prescan's estimate), ÷ 3 for a
            # candidate cut by the ROI margin (an object reaching in from outside the TROI)
            ys, xs = np.nonzero(gm)
            fx0, fy0, fx1, fy1 = _mask_box(xs, ys, to_full)
            sub = img[max(int(fy0), 0):int(math.ceil(fy1)) + 1, max(int(fx0), 0):int(math.ceil(fx1)) + 1]
            vf = vegetation_index(sub, gains=gains, lab=vivid)
            mf = vf > 0.5 * (thr + soil_level)
            f["mass_full"] = float(np.count_nonzero(mf)) / (sx * sy)
            yy, xx = np.nonzero(mf)
            if len(xx) >= 3:
                f["elong_full"] = elongation(xx, yy)
            else:
                f["elong_full"] = 1.0
            cut = bool(np.any(gm & rim))
            cf = to_full(np.array([xs.mean(), ys.mean()]))  # centroid in the full image
            g = roi.on_ground(cf) if roi is not None else None
            if g is not None:  # distance from X_w and green area on the ground (in X_w's pixels), not in the image
                f["d"], f["mass_full"] = g[0], f["mass_full"] * g[1]
            f["score"] = f["mass_full"] * math.exp(-0.5 * (f["d"] / CENTRAL_SIGMA) ** 2) * (0.33 if cut else 1.0)
            # a straight thin piece at full resolution is straw, not a weed (measured: weeds ≤ 4.5)
            if f["elong_full"] > STRAW_ELONG_FULL and not green_blade(f):
                f["score"] = 0.0
            # the TROI holds the weed's centre (the margin is for overhanging leaves only)
            if roi is not None and not roi.contains(cf[None], 1.0)[0]:
                f["score"] = 0.0
            if f["score"] > 0 and first is not None:
                box = (fx0, fy0, fx1, fy1)
        else:
            f["score"] = 0.0
        scored.append((f["score"], gm, f["area"], box, f))
        if debug is not None:
            ys, xs = np.nonzero(gm)
            f["c"] = [float(c) for c in to_full(np.array([xs.mean(), ys.mean()]))]
            f["bb"] = list(_mask_box(xs, ys, to_full))
            f.update(sig=sig, thr=thr - soil_level, soil=soil_level)
            debug.setdefault("cands", []).append(f)
    if not scored:
        return Detection(None, 0.0, "no_plant")
    scored.sort(key=lambda t: -t[0])
    best_score, best_f = scored[0][0], scored[0][4]
    if first is not None:
        first["contenders"] = [t[3] for t in scored if t[3] is not None and t[0] >= AMBIGUOUS * best_score]
        first["best"] = best_score  # vegetation area × centrality (see above), stage-1 pixels
        first["feat"] = best_f
        first["box"] = scored[0][3]  # the chosen plant's full-image box (None if its score is 0)
    return _Choice(vivid, gains, thr, soil_level, contrast, lab, scored)


SPLIT_GREEN = True  # first look: a dropped component's green part is judged on its own (`_green_part`)
SPLIT_MIN = 2.0  # × the minimum component area: smaller dropped components are not split
SPLIT_GM = 0.05  # pixel (G − (R + B)/2)/(R + G + B + 30) before the white balance from which it is green
SPLIT_SHARE, SPLIT_REST = 0.15, 0.3  # the green part: ≥ this share of the component, leaving ≥ this share
SPLIT_RAW, SPLIT_GM_MED, SPLIT_SAT_RAW = 0.01, 0.08, 0.23  # and beyond `plant_like`, clearly green in the camera's
# colours: g_raw, gm_raw and sat_raw medians ≥ these. Measured (session 22): other renderer no ROI seeds 0–2
# found 91/92/90 → 92/92/92 % (a rosette touching a larger pale stone on dark red soil: no_plant → 0.18 S);
# bench seeds 0–7, photo-like seeds 3–6, stones_on_soils.py (31 of 384) and 200 fresh bare scenes (196)
# unchanged but two grass answers (23.1 → 21.6, 2.9 → 6.7 mm). Looser (pixel 0.03, no raw clauses, no
# SPLIT_REST, both looks): other renderer +7 found, but 2 bench bare-soil frames answered a plant (soil
# tints: the greenest pixels of any patch pass the colour rules), a grass blade with a seedling became a
# plant (seed 3 case 37: 1.6 → 260 mm) and, in −a*, an ambiguous seedling a wrong one (seed 4 case 117).
# Pale blue-green plants (gm_raw 0.05–0.06 when split) stay out: bare soil tints measured the same


def _kept(f: dict, vivid: bool) -> bool:
    """Whether a stage-1 component stays (may be grouped with others): plant-coloured, and not a
    long straight piece whose raw colour is not green (straw that the soil white balance turned
    green would drag a plant's centre it joined)."""
    return plant_like(f, vivid) and not (f["elong"] > STRAW_ELONG and f["g_raw"] < STRAW_RAW)


def _clearly_green(f: dict) -> bool:
    """A split-off green part's colour in the camera's own colours (SPLIT_RAW, SPLIT_GM_MED, SPLIT_SAT_RAW)."""
    return f["g_raw"] >= SPLIT_RAW and f["gm_raw"] >= SPLIT_GM_MED and f["sat_raw"] >= SPLIT_SAT_RAW


def _green_part(sub: np.ndarray, bgr: np.ndarray, min_area: float) -> np.ndarray | None:
    """The largest connected part of a stage-1 candidate mask `sub` whose pixels are green above
    magenta in the camera's own colours ((G − (R + B)/2)/(R + G + B + 30) ≥ SPLIT_GM; `bgr`: the
    stage-1 colours under `sub`), if it is ≥ min_area and ≥ SPLIT_SHARE of the candidate and
    leaves ≥ SPLIT_REST of it (a second material, not the plant's own rim); else None."""
    b, g, r = cv2.split(bgr.astype(np.float32))
    gm = (g - 0.5 * (b + r)) / (b + g + r + 30)
    green = sub & (gm >= SPLIT_GM)
    n_sub = int(np.count_nonzero(sub))
    n, lab2, st2, _ = components(green)
    if n <= 1:
        return None
    c = 1 + int(np.argmax(st2[1:, cv2.CC_STAT_AREA]))
    a = int(st2[c, cv2.CC_STAT_AREA])
    if a < min_area or a < SPLIT_SHARE * n_sub or a > (1 - SPLIT_REST) * n_sub:
        return None
    return lab2 == c


def _merge_gap(f: dict, f0: dict | None) -> float:
    """How far (× the union's diameter) candidate `f` may lie from the best candidate `f0`'s
    union to join it: MERGE_GAP, or MERGE_GAP_SAME if it has f0's colour (a clover's trefoils on
    long petioles are one plant's leaves, as far apart as the plant is wide); f0 None: MERGE_GAP."""
    same = f0 is not None and abs(f["gb"] - f0["gb"]) <= SAME_GB and abs(f["sat"] - f0["sat"]) <= SAME_SAT
    return MERGE_GAP_SAME if same else MERGE_GAP


def _locate(img: np.ndarray, win: _Window, choice: _Choice, debug: dict | None = None) -> Detection:
    """Stage 2 of one look: the centre of the best-scored plant of `choice` (joined with near-equal
    candidates close to it), whether it is cut by the border or ambiguous, and a confidence."""
    H, W = img.shape[:2]
    roi, x0, y0, x1, y1, sx, sy = win.roi, win.x0, win.y0, win.x1, win.y1, win.sx, win.sy
    vivid, gains, thr, soil_level, contrast, lab, scored = (choice.vivid, choice.gains, choice.thr, choice.soil_level,
                                                            choice.contrast, choice.lab, choice.scored)
    best_score, gmask = scored[0][0], scored[0][1]
    to_full = win.to_full
    if best_score <= 0:
        return Detection(None, 0.0, "no_plant")
    runner = scored[1][0] / best_score if len(scored) > 1 else 0.0
    if runner > AMBIGUOUS or (roi is not None and runner >= PART_MERGE):
        # near-equal candidates close together are parts of one plant (clover trefoils whose
        # stalks are too thin to segment): grow the best by every scored candidate within
        # MERGE_GAP × the union's diameter, and score what is left against the union. Within a
        # TROI, smaller parts (≥ PART_MERGE of the best) join too: a clover's trefoils are of
        # uneven size, and the centre is between them, not on the largest; those of the best's
        # colour may lie farther (`_merge_gap`; not among near-equal contenders: three equal grey
        # stones that the colour rules took were "ambiguous", and would have been one plant)
        low = 0.0 if runner > AMBIGUOUS else PART_MERGE * best_score
        best_f0 = scored[0][4] if runner <= AMBIGUOUS else None
        rest = [t for t in scored[1:] if t[0] > low]
        while True:
            ys2, xs2 = np.nonzero(gmask)
            diam = math.hypot(np.ptp(xs2) + 1, np.ptp(ys2) + 1)
            dist = cv2.distanceTransform((~gmask).astype(np.uint8), cv2.DIST_L2, 3)
            near = [t for t in rest if float(dist[t[1]].min()) < _merge_gap(t[4], best_f0) * diam]
            if not near:
                break
            for t in near:
                gmask = gmask | t[1]
                best_score += t[0]
            rest = [t for t in rest if not any(t is u for u in near)]
        runner = max((t[0] for t in rest), default=0.0) / best_score
    if debug is not None:  # the stage-1 mask: 1 every component, 2 the plant located (after merging)
        full = np.zeros((H, W), np.uint8)
        lbl = np.where(gmask, 2, (lab > 0).astype(np.uint8)).astype(np.uint8)
        full[y0:y1, x0:x1] = cv2.resize(lbl, (x1 - x0, y1 - y0), interpolation=cv2.INTER_NEAREST)
        debug["mask_full"] = full

    # ---- stage 2: centre on a plant-normalised grid from the full-resolution crop
    ys, xs = np.nonzero(gmask)
    bx0, by0, bx1, by1 = _mask_box(xs, ys, to_full)
    centre, tips, sharp = _centre_fullres(img, (bx0, by0, bx1, by1), thr, soil_level, gains, roi, debug, lab_index=vivid,
                                          stage1=(gmask, x0, y0, sx, sy))
    if centre is None:
        return Detection(None, 0.0, "no_plant")

    # ---- border, ambiguity, confidence
    size = max(bx1 - bx0, by1 - by0)
    border_d = min(centre[0] + 0.5, centre[1] + 0.5, W - 0.5 - centre[0], H - 0.5 - centre[1])
    touches = bx0 <= 1 or by0 <= 1 or bx1 >= W - 2 or by1 >= H - 2
    if touches and border_d < 0.15 * size:
        return Detection(None, 0.1, "cut_by_border")
    conf = min(1.0, contrast / 0.1) * (0.6 + 0.4 * min(1.0, tips / 3)) * (1 - 0.7 * runner) * (0.7 + 0.3 * sharp)
    if touches:
        conf *= 0.8
    if roi is not None and not roi.contains(centre[None], 1.0)[0]:
        conf *= 0.6
    pix = (float(centre[0]), float(centre[1]))
    if runner > AMBIGUOUS:
        return Detection(pix, float(np.clip(conf, 0, 0.3)), "ambiguous")
    return Detection(pix, float(np.clip(conf, 0.0, 1.0)))


# ---- pieces ------------------------------------------------------------------------------------
ONE_PEAK_HUB = 0.145  # a plant of ≥ 2 separate parts but one vote peak (small trefoils on long petioles read as
# thin) gets `compound_centre` if its strongest three-lobed hub reaches this (bench seeds 0–7, one-peak plants
# that compound_centre would answer: rosettes and grass ≤ 0.138, clovers ≥ 0.146; answers: 4 clovers 38.0 → 1.9,
# 25.5 → 1.6, 22.4 → 1.1, 18.8 → 13.9 mm, a rosette of 0.159 1.4 → 20.8 mm). Its compound flag is not used
# (rosettes with such hubs went to the geometric median: ~30 answers worse)
STALK_PEAKS = 2  # leaf-axis vote peaks (`plant_centre.vote_peaks`) from which stalks are looked for


def _stalk_centre(img: np.ndarray, X0: int, Y0: int, kx: float, ky: float, plant: np.ndarray, gains: np.ndarray,
                  lab_index: bool, thr: float, soil: float) -> tuple[np.ndarray | None, np.ndarray | None]:
    """`stalks.stalk_points` (stalks' meeting point, lone stalk's centre end) for a plant on the
    stage-2 grid (grid pixel (j, i) ↔ image (X0 + (j + 0.5)·kx − 0.5, Y0 + (i + 0.5)·ky − 0.5)).
    It works at the image's own pitch (stalks are 1–3 px wide there; coarser only for plants
    over stalks.MAX_PX), on a window reaching stalks.MARGIN × the plant's size round it (a
    clover's centre may lie outside the leaves that stage 1 grouped); answers in stage-2 grid
    pixels."""
    if not stalks.has_leaf_clusters(plant):  # (cheap, on the stage-2 grid: most plants stop here)
        return None, None
    nh, nw = plant.shape
    H, W = img.shape[:2]
    span = max(nw * kx, nh * ky)  # the stage-2 window in image pixels
    p = max(1.0, span / stalks.MAX_PX)  # pitch of the stalk grid, image pixels
    m = stalks.MARGIN * span
    xa, ya = max(int(math.floor(X0 - m)), 0), max(int(math.floor(Y0 - m)), 0)
    xb, yb = min(int(math.ceil(X0 + nw * kx + m)), W), min(int(math.ceil(Y0 + nh * ky + m)), H)
    if xb - xa < 16 or yb - ya < 16:
        return None, None
    NW, NH = max(int((xb - xa) / p), 8), max(int((yb - ya) / p), 8)
    region = resize_down(img[ya:yb, xa:xb], (NW, NH)) if p > 1.0 else img[ya:yb, xa:xb]
    p_x, p_y = (xb - xa) / region.shape[1], (yb - ya) / region.shape[0]  # the grid's pitch, image px
    grey = cv2.cvtColor(region, cv2.COLOR_BGR2GRAY).astype(np.float32) / 255.0
    vi = vegetation_index(region, gains=gains, lab=lab_index).astype(np.float32)
    # the plant's mask onto this grid: stalk-grid pixel x ↔ image xa + (x + 0.5)·p_x − 0.5 ↔
    # stage-2 grid (xa + (x + 0.5)·p_x − 0.5 − X0 + 0.5) / kx − 0.5 (and the same for y)
    M = np.array([[p_x / kx, 0, (xa - X0 + 0.5 * p_x) / kx - 0.5], [0, p_y / ky, (ya - Y0 + 0.5 * p_y) / ky - 0.5]], np.float32)
    NH, NW = region.shape[:2]
    big = cv2.warpAffine(plant.astype(np.uint8), M, (NW, NH), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                         borderMode=cv2.BORDER_CONSTANT) > 0
    leaves = _hysteresis(vi, thr, soil, np.ones(vi.shape, bool)) | big
    def to_stage2(X: np.ndarray | None) -> np.ndarray | None:
        if X is None:
            return None
        x, y = xa + (X[0] + 0.5) * p_x - 0.5, ya + (X[1] + 0.5) * p_y - 0.5  # image pixels
        return np.array([(x - X0 + 0.5) / kx - 0.5, (y - Y0 + 0.5) / ky - 0.5])

    meet, lone = stalks.stalk_points(grey, vi, leaves, big)
    return to_stage2(meet), to_stage2(lone)


def _mask_box(xs: np.ndarray, ys: np.ndarray, to_full) -> tuple[float, float, float, float]:
    """Full-image box (x0, y0, x1, y1) of stage-1 grid pixels (xs, ys)."""
    fx0, fy0 = to_full(np.array([xs.min() - 0.5, ys.min() - 0.5]))
    fx1, fy1 = to_full(np.array([xs.max() + 0.5, ys.max() + 0.5]))
    return float(fx0), float(fy0), float(fx1), float(fy1)


def _roi_mask(roi: Roi, shape: tuple[int, int], x0: float, y0: float, sx: float, sy: float) -> np.ndarray:
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


MID_PX_STAGE1 = 250_000  # pixels of the intermediate image the index is computed on (stage 1)
MID_PX_STAGE2 = 120_000  # same for the plant crop (stage 2)


def _threshold(v: np.ndarray) -> tuple[float, float, float]:
    """(threshold, soil level, contrast) of the index over the search window.

    Soil is the bulk of the pixels; its spread σ is measured from the median to the 90th
    percentile (plants rarely fill a tenth of a TROI view; the lower side, or the smaller of the
    two, measured worse on bench seeds 0–3: more wrong centres). When a plant does fill ≥ a
    tenth of the window (a close-up, a photo without a ROI: the 90th percentile lands on
    leaves), the soil is the lower class of an Otsu split whose upper class is green and
    ≥ BIG_SEP σ above it (dull rosettes covering 11–15 % of a frame: 13 of 30 "no_plant" → 4;
    bench seeds 0–3: two frames of 1200 moved by ≤ 0.3 mm). Vegetation must stand
    5 σ above the soil level, with the threshold kept within G* ∈ [0, 0.10] (the old floor 0.02
    lost olive grass and yellow-green seedlings; the per-candidate colour rule `plant_like`
    now keeps bare soil empty).
    """
    v = v.ravel()
    lo, med, p90, hi = percentile(v, (0.5, 50, 90, 99.5))  # one partition
    sig = max((p90 - med) / 1.28, 0.004)
    if p90 > med:
        # a plant filling ≥ a tenth of the window (a close-up, a photo without a ROI) puts the
        # 90th percentile, or the median, on leaves: then the soil is the lower class of a
        # two-class (Otsu) split of the index, when the upper one is green and far above it
        if hi > lo:
            q = np.clip((v - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)
            t, _ = cv2.threshold(q.reshape(1, -1), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
            t = lo + t * (hi - lo) / 255.0
            n_low = int(np.count_nonzero(v <= t))
            frac = 1.0 - n_low / len(v)
            up = v[v > t] if frac >= BIG_PLANT and n_low > 100 else v[:0]
            # (the upper class's median is > 0 only if at least half of it is; on most frames
            # Otsu splits a mottled soil and the upper class is soil, G* < 0: no percentiles then)
            if len(up) and 2 * np.count_nonzero(up > 0) >= len(up):
                m_l, p_l = percentile(v[v <= t], (50, 90))
                s_l = max((p_l - m_l) / 1.28, 0.004)
                m_u = median(up)
                if m_u > 0 and m_u - m_l >= BIG_SEP * s_l:
                    med, sig = m_l, s_l
    thr = float(np.clip(med + THR_SIGMAS * sig, THR_FLOOR, 0.10))
    above = v[v > thr]
    contrast = float(np.float32(median(above)) - med) if len(above) else 0.0  # (float32, as np.median's was)
    return thr, med, contrast


BIG_PLANT, BIG_SEP = 0.1, 8.0  # upper Otsu class share, and its median over the lower's in the lower's σ
THR_FLOOR = 0.0  # G* > 0: green above both red and blue; soil/stone/straw are rejected per candidate
THR_SIGMAS = 5.0


def _hysteresis(vi: np.ndarray, thr: float, soil: float, inside: np.ndarray) -> np.ndarray:
    """Pixels halfway from soil to thr connected to a pixel above thr (keeps stems, leaf margins)."""
    strong = (vi > thr) & inside
    strong = cv2.morphologyEx(strong.astype(np.uint8), cv2.MORPH_OPEN, np.ones((2, 2), np.uint8)).astype(bool)
    weak = (vi > 0.5 * (thr + max(soil, 0.0))) & inside
    n, lab = cv2.connectedComponents(weak.astype(np.uint8), connectivity=8)
    keep = np.zeros(n, bool)
    keep[lab[strong]] = True  # (repeated labels set the same flag: no need to sort them out)
    keep[0] = False
    return np.take(keep, lab)  # = keep[lab], ~2× faster than fancy indexing


CENTRAL_SIGMA = 0.8  # of the ROI radius: how fast the candidate score falls off from the TROI centre
VIVID_WB = 0.5  # exponent on the soil white balance in the second look: half (a full pull towards a reddish
# soil turns yellow-green leaves on grey-olive soil orange; none measured 0.4 % fewer detections)
VIVID_AREA = 3.0  # × the minimum component area (a 20-px green speck on bare soil came up; 4.0 until
# session 13: bench seed 1 case 1, a seedling of 41 stage-1 px under 4 × 11.8, lost to a distractor 63 mm away; 3.0 moved
# no bench bare-soil frame, none of 200 fresh bare scenes or bench/stones_on_soils.py, bench wrong 25 → 24)


def _local_contrast(img: np.ndarray, sub: np.ndarray, origin: tuple[int, int], win: "_Window", gains: np.ndarray,
                    thr: float, soil: float) -> tuple[float, float]:
    """(local contrast, core share) of a stage-1 candidate mask `sub` whose top-left grid cell is
    `origin`: at full resolution, (median −a* index of its pixels − median in a ring ~1–4 px
    round them: a 9 × 9 dilation minus a 3 × 3 one) / the ring's σ; and the share of `sub` left after a 3 × 3 erosion."""
    l0, t0 = origin
    h0, w0 = sub.shape
    sp = np.pad(sub.astype(np.uint8), 1)
    core = float(np.count_nonzero(cv2.erode(sp, np.ones((3, 3), np.uint8)))) / max(float(np.count_nonzero(sp)), 1.0)
    p = int(math.ceil((LC_RING[1] // 2 + 2) / min(win.sx, win.sy))) + 1  # grid cells of margin for the ring
    xa, xb = int(round(win.x0 + (l0 - p) * win.sx)), int(round(win.x0 + (l0 + w0 + p) * win.sx))
    ya, yb = int(round(win.y0 + (t0 - p) * win.sy)), int(round(win.y0 + (t0 + h0 + p) * win.sy))
    H, W = img.shape[:2]
    cx0, cy0, cx1, cy1 = max(xa, 0), max(ya, 0), min(xb, W), min(yb, H)
    if cx1 - cx0 < 4 or cy1 - cy0 < 4:
        return 0.0, core
    full = cv2.resize(np.pad(sub.astype(np.uint8), p), (xb - xa, yb - ya), interpolation=cv2.INTER_NEAREST)
    full = full[cy0 - ya:cy1 - ya, cx0 - xa:cx1 - xa]
    vf = vegetation_index(img[cy0:cy1, cx0:cx1], gains=gains, lab=True)
    m = ((vf > 0.5 * (thr + soil)) & (full > 0)).astype(np.uint8)
    if int(m.sum()) < 4:
        return 0.0, core
    a, b = LC_RING
    ring = cv2.dilate(m, np.ones((b, b), np.uint8)) > cv2.dilate(m, np.ones((a, a), np.uint8))
    if int(ring.sum()) < 8:
        return 0.0, core
    rv = vf[ring]
    return (median(vf[m > 0]) - median(rv)) / max(float(rv.std()), 1e-4), core


GROUP_GAP = 0.35  # × the group's diameter: largest gap a component may be joined across
AMBIGUOUS = 0.8  # runner-up score / best score above which the choice is "ambiguous" ...
MERGE_GAP = 0.5  # ... unless the contenders lie within this × the union's diameter: one plant
# (seed 1 case 207: a clover in two halves 0.38 diameters apart; 0.7 joined a third plant)
PART_MERGE = 0.3  # with a ROI, candidates scoring ≥ this × the best also join it within MERGE_GAP (bench
# seeds 0–7: 5 clovers better (46 → 1.1, 31.8 → 0.3, 25.7 → 6.2 mm), 2 worse (0.8 → 12.1, 1.3 → 2.2 mm);
# 0.15 the same; 0.5 only one better. Without a ROI it gave photo-like seed 4 a wrong answer: not there)
MERGE_GAP_SAME = 1.0  # ... and within this × the diameter if of the best's colour (|Δgb| ≤ SAME_GB, |Δsat| ≤
SAME_GB, SAME_SAT = 0.02, 0.05  # SAME_SAT): trefoils on long petioles (bench seeds 0–7: a clover 38.5 → 0.6 mm,
# one 23.1 → 25.5 mm; 1.5 joined 3 seedlings to distractors). Among near-equal contenders too it fixed a clover
# (46.2 → 3.4 mm), but stones_on_soils.py answered 35 of 384 frames, not 31: three equal stones as one plant


def _group(lab: np.ndarray, stats: np.ndarray, comps: list[int]) -> list[list[int]]:
    """Join components separated by a gap smaller than GROUP_GAP × the larger one's diameter.

    Largest first: a group grows by every smaller component whose nearest pixel is within
    GROUP_GAP × the group's diameter (distance transform of the group, minimum per label).
    """
    comps = sorted(comps, key=lambda k: -stats[k, cv2.CC_STAT_AREA])
    if not comps:
        return []
    idx = np.asarray(comps)
    groups: list[list[int]] = []
    used: set[int] = set()
    for k in comps:
        if k in used:
            continue
        g = [k]
        used.add(k)
        while True:
            # the group's pixel extent is the union of its components' boxes (no mask needed)
            gx0 = int(stats[g, cv2.CC_STAT_LEFT].min())
            gy0 = int(stats[g, cv2.CC_STAT_TOP].min())
            gx1 = int((stats[g, cv2.CC_STAT_LEFT] + stats[g, cv2.CC_STAT_WIDTH]).max()) - 1
            gy1 = int((stats[g, cv2.CC_STAT_TOP] + stats[g, cv2.CC_STAT_HEIGHT]).max()) - 1
            diam = math.hypot(gx1 - gx0 + 1, gy1 - gy0 + 1)
            # only components whose box comes within reach can join: crop to that window
            r = int(math.ceil(GROUP_GAP * diam)) + 1
            y0, y1 = max(gy0 - r, 0), min(gy1 + r + 1, lab.shape[0])
            x0, x1 = max(gx0 - r, 0), min(gx1 + r + 1, lab.shape[1])
            cand = [m for m in comps if m not in used and stats[m, cv2.CC_STAT_AREA] <= stats[k, cv2.CC_STAT_AREA]
                    and stats[m, cv2.CC_STAT_LEFT] < x1 and stats[m, cv2.CC_STAT_LEFT] + stats[m, cv2.CC_STAT_WIDTH] > x0
                    and stats[m, cv2.CC_STAT_TOP] < y1 and stats[m, cv2.CC_STAT_TOP] + stats[m, cv2.CC_STAT_HEIGHT] > y0]
            if not cand:
                break
            sub = lab[y0:y1, x0:x1]
            dist = cv2.distanceTransform((~np.isin(sub, g)).astype(np.uint8), cv2.DIST_L2, 3)
            dmin = ndimage.minimum(dist, sub, cand)
            new = [m for m, d in zip(cand, np.atleast_1d(dmin)) if np.isfinite(d) and d < GROUP_GAP * diam]
            if not new:
                break
            g += new
            used.update(new)
        groups.append(g)
    del idx
    return groups


def _separate_parts(plant: np.ndarray) -> int:
    """Number of the plant mask's connected parts of ≥ 2 % of its area."""
    n, _, stats, _ = components(plant)
    return int(np.count_nonzero(stats[1:, cv2.CC_STAT_AREA] >= 0.02 * stats[1:, cv2.CC_STAT_AREA].sum()))


def _centre_fullres(img, box, thr: float, soil: float, gains: np.ndarray, roi: Roi | None, debug: dict | None = None,
                    lab_index: bool = False, stage1: tuple | None = None):
    """Centre of the plant in `box` (full-image pixels). Returns (uv, n_tips, sharpness); `debug`
    gets the name of the estimator that gave it under "method"."""
    H, W = img.shape[:2]
    bx0, by0, bx1, by1 = box
    m = 0.12 * max(bx1 - bx0, by1 - by0) + 2
    X0, Y0 = max(int(math.floor(bx0 - m)), 0), max(int(math.floor(by0 - m)), 0)
    X1, Y1 = min(int(math.ceil(bx1 + m)), W), min(int(math.ceil(by1 + m)), H)
    crop = img[Y0:Y1, X0:X1]
    k = PLANT_PX / max(bx1 - bx0, by1 - by0)
    nw, nh = max(4, round(crop.shape[1] * k)), max(4, round(crop.shape[0] * k))
    kx, ky = crop.shape[1] / nw, crop.shape[0] / nh
    vi = pooled_index(crop, gains, (nw, nh), MID_PX_STAGE2, lab=lab_index, exact=True)
    inside = np.ones(vi.shape, bool)
    if roi is not None:
        inside = _roi_mask(roi, vi.shape, X0, Y0, kx, ky)
    mask = _hysteresis(vi, thr, soil, inside)
    n, lab, stats, _ = components(mask)
    if n <= 1:
        return None, 0, 0.0
    g = None
    if stage1 is not None:
        # the plant is what stage 1 chose (colour-checked, grouped): the components that overlap
        # its mask; straw or stones next to the plant must not become its stalks
        gm1, x1_0, y1_0, s1x, s1y = stage1
        gm1 = cv2.dilate(gm1.astype(np.uint8), np.ones((3, 3), np.uint8))
        jj = ((X0 + (np.arange(nw) + 0.5) * kx - 0.5) - x1_0 + 0.5) / s1x - 0.5
        ii = ((Y0 + (np.arange(nh) + 0.5) * ky - 0.5) - y1_0 + 0.5) / s1y - 0.5
        jj = np.clip(np.rint(jj).astype(int), 0, gm1.shape[1] - 1)
        ii = np.clip(np.rint(ii).astype(int), 0, gm1.shape[0] - 1)
        keep = gm1[np.ix_(ii, jj)] > 0
        g = [c for c in np.unique(lab[keep & (lab > 0)]) if stats[c, cv2.CC_STAT_AREA] >= 3] or None
    if g is None:
        # keep the components of this plant: the largest and those within reach of it
        big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        groups = _group(lab, stats, [c for c in range(1, n) if stats[c, cv2.CC_STAT_AREA] >= 3])
        g = next(gr for gr in groups if big in gr)
    plant = np.isin(lab, g)
    if int(plant.sum()) < 3:
        return None, 0, 0.0
    dtp = cv2.distanceTransform(plant.astype(np.uint8), cv2.DIST_L2, 3)
    ys_, xs_ = np.nonzero(plant)
    size = math.hypot(np.ptp(xs_) + 1, np.ptp(ys_) + 1)
    roundness = float(dtp[plant].mean()) / size  # mean half-width of the parts / plant size
    uv, method = None, None
    ntips, sharp = 3, 1.0  # confidence inputs when a stalk/part arrangement gives the centre
    # a fan (blades leaning one way from one base) first: its leaf axes converge at one end,
    # where no middle-of-the-parts estimate lands (not for broad leaves, whose outlines vote
    # across the plant: a half-disc of leaves had its "apex" on its rim, 0.43 L off)
    votes, n_peaks = None, 0  # leaf-axis votes: made when first needed (~1–2 ms)
    if roundness < plant_centre.THIN_ROUND:  # blades: their edges run along them, towards the base
        votes = plant_centre.axis_votes(vi, plant, size)
        n_peaks = plant_centre.vote_peaks(votes, size)
        uv = plant_centre.fan_apex(plant, votes, size, n_peaks)
        if uv is not None:
            method = "fan_apex"
    # plants with broad, rounded parts (clover trefoils, seedlings): trust where stalks or thin
    # parts meet, then (below) where trefoils point away from, or the middle of the parts
    # arranged round an empty centre; blades and narrow leaves (and round plants where none of
    # these applies): the tree median, computed only then
    parts = None  # (size, broad-parts mask): made when first needed, shared by the estimators below
    if uv is None and roundness >= plant_centre.HUB_MIN_ROUND:
        parts = plant_centre.broad_parts(plant)
        for name, fn in (("petiole_centre", lambda: plant_centre.petiole_centre(plant, vi, soil, thr, parts)),
                         ("line_hub", lambda: plant_centre.line_hub(plant, parts))):
            uv = fn()
            if uv is not None and not plant_centre.within_broad_hull(uv, parts):
                uv = None  # stalk-like lines outside the leaves (straw next to the plant)
            if uv is not None:
                method = name
                break
    if uv is None and votes is None:
        votes = plant_centre.axis_votes(vi, plant, size)
        n_peaks = plant_centre.vote_peaks(votes, size)
    compound = False
    hubs = None
    lone = None  # the centre end of a lone stalk between two leaf clusters (after compound_centre)
    if uv is None and n_peaks >= STALK_PEAKS:
        uv, lone = _stalk_centre(img, X0, Y0, kx, ky, plant, gains, lab_index, thr, soil)
        if uv is not None:
            method = "stalk_centre"
    if uv is None and (n_peaks >= 2 or n_peaks == 1 and _separate_parts(plant) >= 2):
        # compound leaves (clover trefoils: leaf axes converge at several hubs) whose stalks do
        # not show: the rays back from the hubs (after the stalk estimators, which are exact
        # when they answer: 0.3–2 mm cases became 5–12 mm when this came first)
        hubs = compound_leaf.compound_hubs(plant, vi, soil, size)
        if n_peaks < 2 and compound_leaf.strongest_hub(hubs) < ONE_PEAK_HUB:
            hubs = None
        else:
            uv = compound_leaf.compound_centre(plant, vi, soil, hubs)
            if uv is not None:
                method = "compound_centre"
            compound = n_peaks >= 2 and compound_leaf.has_compound_leaves(hubs)
    if uv is None and lone is not None:
        # one stalk carrying a leaf away from the rest of the plant: its end at the rest (after
        # compound_centre, exact when its rays agree; before the medians of the parts)
        uv, method = lone, "lone_stalk"
    if uv is None and roundness >= plant_centre.HUB_MIN_ROUND:
        # separate parts round an empty centre (stalks too thin to see): the median of their
        # centroids — after `compound_centre`, which answers exactly for trefoils whose
        # middle leaflets point away from the centre (first, it took 13 of 24 stalkless
        # other-renderer clovers at 0.2–0.4 R off; after: those went to `compound_centre`)
        uv, method = plant_centre.component_median(plant), "component_median"
        if uv is None:
            # two parts (two leaves, stem unseen): where they are closest
            uv, method = plant_centre.pair_gap(plant), "pair_gap"
        if uv is not None:
            parts = parts or plant_centre.broad_parts(plant)
            uv = uv if plant_centre.within_broad_hull(uv, parts) else None
        if uv is None:
            method = None
    scattered = bool(plant_centre.SCATTER_PEAKS) and n_peaks >= plant_centre.SCATTER_PEAKS
    gmed = None  # the plant's geometric median: made when first needed
    if uv is None and not compound and (scattered or n_peaks >= leaf_axes.MIN_PEAKS and roundness >= leaf_axes.MIN_ROUND) \
            and compound_leaf.strongest_hub(hubs) < leaf_axes.HUB_GUARD:
        # leaf axes votes with several peaks (a rosette's broad leaves: their edges vote
        # everywhere, and the middle of the mask is pulled towards the biggest leaves): where the
        # leaves' axes traced back from their tips meet. Not when three-lobed hubs show (leaflet
        # axes meet at their trefoil's hub, not at the plant's centre), nor for 3 peaks of thin
        # blades (grass: the tree median and its votes find their base)
        gmed = plant_centre.geometric_median(np.c_[xs_, ys_].astype(float))
        met = leaf_axes.tip_axes_centre(plant, gmed)
        if met is not None:
            uv, method = met[0], "tip_axes"
    if uv is None:
        if compound or scattered:
            # leaf axes converge at many separate points (the hubs of compound leaves, e.g.
            # clover trefoils whose rays back did not meet, or the bases of scattered seedling
            # leaves, or the broad leaves of a rosette whose edges vote everywhere, where the
            # leaf axes did not meet either): no single apex in the votes (the tree median
            # slides along a trefoil's stalk: 15–46 mm off); the middle the parts are arranged
            # around
            method = "geometric_median"
            uv = gmed if gmed is not None else plant_centre.geometric_median(np.c_[xs_, ys_].astype(float))
    if uv is None:
        method = "tree_median"
        # leaf-axis votes for the tree median at the scale of the leaves' half-width: a smaller
        # window leaves the two edges of a broad leaf voting along two parallel lines that
        # miss its axis (and the centre) by the half-width
        scale = float(np.clip(plant_centre.AXIS_K * roundness, 0.015, plant_centre.AXIS_MAX))
        fine = scale <= 0.015 or roundness >= plant_centre.THIN_ROUND  # votes unused for round parts (weight 0)
        uv, ntips, sharp = plant_centre.tree_median(plant, vi, None, votes if fine else plant_centre.axis_votes(vi, plant, size, scale))
        if uv is None:
            return None, 0, 0.0
    if debug is not None:
        debug["method"] = method
        debug["roundness"] = roundness
    return np.array([X0 + (uv[0] + 0.5) * kx - 0.5, Y0 + (uv[1] + 0.5) * ky - 0.5]), ntips, sharp
