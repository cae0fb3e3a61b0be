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
     leaves) that accepts vivid plants only; a window that a large cast shadow splits gets both
     looks again in its lit and its shadowed part, each with its own soil statistics
     (`capm_field.shadow_regions`): their plant is the answer where the whole window found none,
     and replaces the whole window's answer if it is another plant scoring higher;
  3. stage 2, find its centre (`capm_field.centre_cascade`): the chosen plant re-cut from the
     full-resolution frame at ~PLANT_PX across, centre from `capm_field.plant_centre` (stalk
     crossings, the tree median of geodesic distances to the leaf tips with leaf-axis votes, or
     the geometric median of plants whose leaf axes converge at many points),
     `capm_field.compound_leaf` (clover trefoils) or `capm_field.leaf_axes` (rosettes: where the
     leaves' axes meet);
  4. "cut_by_border" when the plant touches the frame edge near the centre; confidence.
The pixel returned follows the camera module's convention (pixel centres at integer coordinates);
`capm_field.camera.PinholeCamera.pixel_to_ground` maps it to the field (H⁻¹). Measured figures
and the reasons behind each threshold: docs/perception.md. The index images are made in
`capm_field.vegetation`, thresholded and grouped in `capm_field.vegetation_mask`; candidates are
measured and judged in `capm_field.candidates`; the ROI is `capm_field.roi`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from typing import Literal

import cv2
import numpy as np

from .camera import PinholeCamera
from .candidates import (LC_RING, STRAW_ELONG, STRAW_ELONG_FULL, STRAW_RAW, candidate_features, contrast_band,
                         green_blade, plant_like)
from .centre_cascade import centre_fullres
from .components import components
from .order_stats import elongation, median, percentile
from .roi import ROI_MARGIN, Roi, RoiLike, as_roi, roi_from_troi, roi_mask
from .shadow_regions import shadow_regions
from .vegetation import downscale, pooled_index, resize_down, soil_gains, vegetation_index
from .vegetation_mask import group_components, hysteresis, threshold

__all__ = ["Detection", "Roi", "RoiLike", "detect_centre", "ground_centre", "roi_from_troi"]

log = logging.getLogger(__name__)

Reason = Literal["no_plant", "ambiguous", "cut_by_border", "bad_image"]

WORK_PX = 320  # stage 1 (find the plant): longest side of the search window after downscaling


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
        det, chosen = _looks(image_bgr, win, debug)
        if det.reason == "no_plant":
            det = _in_shadow_parts(image_bgr, win, debug) or det
        elif det.reason is None:
            # the whole window's statistics may also have hidden the weed in one part while
            # another plant (a small sunlit one) was chosen: a part's plant that is not the
            # chosen one and outscores it replaces it
            det = _in_shadow_parts(image_bgr, win, debug, beat=SHADOW_GAIN * chosen["best"], other=chosen["box"]) or det
        return det
    except Exception:  # the contract is "never raise": a bug must not stop a mission ...
        # ... but it must not go unseen either: the traceback goes to the log (and so the run's)
        log.exception("weed-centre detector failed on a %s %s image; answering bad_image",
                      getattr(image_bgr, "shape", "?"), getattr(image_bgr, "dtype", type(image_bgr).__name__))
        return Detection(None, 0.0, "bad_image")


def _looks(image_bgr: np.ndarray, win: _Window, debug: dict | None) -> tuple[Detection, dict]:
    """Both looks at one window (G*, then CIELAB −a* where G* found no plant, an ambiguous one or a
    small or pale one): the Detection, and the stage-1 "best" score and "feat"ures of the plant it
    answers (an empty dict if none; see `_detect`)."""
    first: dict = {}
    det = _detect(image_bgr, None, debug, first=first, win=win)
    if det.reason in ("no_plant", "ambiguous"):
        # second look on the green–red axis of CIELAB: yellow-green leaves (young seedlings,
        # chlorotic plants, warm light) reflect nearly as much red as green, so G − max(R, B)
        # leaves them at the soil's level; only vivid candidates count (soil tints come up too)
        # (also after an "ambiguous" first look: a pale plant split in two by G* is one in −a*)
        second: dict = {}
        det2 = _detect(image_bgr, None, debug, vivid=True, first=second, win=win)
        if (det.reason == "ambiguous" and det2.reason is None and second["best"] <= SMALL_GAIN * first["best"]
                and not _boxes_meet([second["box"]], first["contenders"])):
            # the second look chose something else than the plants in question, and nothing
            # clearly larger (a vivid speck) (a clover's centre lies between its leaflets'
            # boxes: the chosen plant's box must meet one, not hold the centre)
            return det, first
        if det2.reason is None or (det.reason == "no_plant" and det2.reason != "no_plant"):
            return det2, second
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
                return det2, second
    return det, first


def _in_shadow_parts(image_bgr: np.ndarray, win: _Window, debug: dict | None, beat: float = 0.0,
                     other: tuple | None = None) -> Detection | None:
    """Both looks again in the lit and in the shadowed part of a window that a large cast shadow
    splits (`capm_field.shadow_regions`), each with its own white balance and soil threshold;
    the best-scoring plant of ≥ SHADOW_MIN_PLANT of its part, green in the camera's own colours
    unless ≥ SHADOW_BIG of it, or None. After the whole window's answer (full-image box `other`),
    only a plant whose box does not meet it and that scores above `beat` counts."""
    best: tuple[float, Detection, dict | None] | None = None
    for part, core in shadow_regions(win.small, win.inside):
        n = int(np.count_nonzero(part))
        if n < 16 or np.count_nonzero(core) < 16:
            continue
        sub = replace(win, inside=part, n_in=n, gains=soil_gains(win.small, core), soil=core)
        dbg: dict | None = {} if debug is not None else None  # joins `debug` only if taken
        det, chosen = _looks(image_bgr, sub, dbg)
        if det.reason is not None or (other is not None and _boxes_meet([chosen["box"]], [other])):
            continue
        f = chosen["feat"]
        if (f["area"] >= SHADOW_MIN_PLANT * n and (f["g_raw"] > SHADOW_RAW_G or f["area"] >= SHADOW_BIG * n)
                and chosen["best"] > (beat if best is None else best[0])):
            best = (chosen["best"], det, dbg)
    if best is None:
        return None
    if debug is not None and best[2] is not None:
        _merge_debug(debug, best[2])
        debug["shadow_part"] = True
    return best[1]


SHADOW_GAIN = 1.0  # × the whole window's choice's score that a part's other plant must exceed to replace it
# (session 26, field-photo seeds 0–5 and the photographer's-shadow sets: 2 wrong answers right, fat-hens in
# the shadow outscoring a small sunlit plant by 1.46× and 3.9×; bench seeds 0–7: no answer replaced)
SHADOW_MIN_PLANT = 0.002  # least stage-1 area of a plant found in one part of a shadowed window, × the
# part's pixels: the soil under sky light alone is tinted green where it is yellowish, and specks of it
# and sharpening halos at the shadow's edge (≤ 0.1 % on bare frames) stand out of that part's statistics
SHADOW_RAW_G = 0.0  # its median G − max(R, B) (raw, `g_raw`) must exceed this ... (the lower σ of a part made
SHADOW_BIG = 0.01  # ... unless it is this × its part: olive straws crossing in a bench shadow, g_raw −0.03 and
# 0.3 % of the part, a plant; found weeds have g_raw ≥ 0.004, but for a fat-hen lit by blue sky only, 6 %)


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
    soil: np.ndarray | None = None  # where the soil statistics are measured, if not all of `inside`

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
        roi = as_roi(roi_in)
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
        inside = roi_mask(roi, gray.shape, x0, y0, sx, sy)
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
    at = inside if win.soil is None else win.soil
    n_at = n_in if win.soil is None else int(np.count_nonzero(at))
    thr, soil_level, contrast = threshold(vi[::2, ::2][at[::2, ::2]] if n_at >= 4096 else vi[at])
    mask = hysteresis(vi, thr, soil_level, inside)
    n, lab, stats, cents = components(mask)
    min_area = max(6.0, 1.5e-4 * n_in)
    comps = [k for k in range(1, n) if stats[k, cv2.CC_STAT_AREA] >= min_area]
    if not comps:
        return Detection(None, 0.0, "no_plant")
    # soil spread of the index outside the vegetation mask (robust: median → p90)
    soil_px = vi[::2, ::2][(at & ~mask)[::2, ::2]] if n_at >= 4096 else vi[at & ~mask]
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
    groups = group_components(lab, stats, comps)
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
    centre, tips, sharp = centre_fullres(img, (bx0, by0, bx1, by1), thr, soil_level, gains, roi, debug, lab_index=vivid,
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
def _mask_box(xs: np.ndarray, ys: np.ndarray, to_full) -> tuple[float, float, float, float]:
    """Full-image box (x0, y0, x1, y1) of stage-1 grid pixels (xs, ys)."""
    fx0, fy0 = to_full(np.array([xs.min() - 0.5, ys.min() - 0.5]))
    fx1, fy1 = to_full(np.array([xs.max() + 0.5, ys.max() + 0.5]))
    return float(fx0), float(fy0), float(fx1), float(fy1)


MID_PX_STAGE1 = 250_000  # pixels of the intermediate image the index is computed on (stage 1)
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


