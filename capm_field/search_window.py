"""Stage 0 of the weed-centre detector: the search window of one frame.

The ROI's bounding box grown by ROI_MARGIN, downscaled once to the index image (≤ MID_PX_STAGE1
px) and to the stage-1 grid (≤ WORK_PX on its longest side); the frame's sanity checks (dtype,
shape, exposure, flatness, no colour, pixel noise: "bad_image"), the index image median-filtered when its
colour noise is high (`DENOISE_FROM`), the ROI mask on the grid and the soil white balance. Both
looks of `capm_field.detector` and its shadowed-part looks share it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .detection import Detection
from .roi import ROI_MARGIN, Roi, RoiLike, as_roi, roi_mask
from .vegetation import CLIP_LEVEL, SOIL_CLIPPED, downscale, resize_down, soil_gains, unclipped

WORK_PX = 320  # stage 1 (find the plant): longest side of the search window after downscaling
MID_PX_STAGE1 = 250_000  # pixels of the intermediate image the index is computed on (stage 1)


@dataclass(frozen=True)
class SearchWindow:
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
    soil: np.ndarray | None = None  # where the soil statistics are measured, if not all of `inside` (a shadow's part, unclipped soil)
    noise: float = 0.0  # the index image's pixel-scale colour noise (`chroma_noise` ÷ the resampling factor)
    clipped: np.ndarray | None = None  # over-exposed soil: where red or blue is clipped on the stage-1 grid, if
    # that is ≥ SOIL_CLIPPED of the ROI (`vegetation.cap_clipped`); None otherwise

    @property
    def overexposed(self) -> bool:
        return self.clipped is not None

    def to_full(self, p: np.ndarray) -> np.ndarray:
        """Stage-1 grid point (j, i) → full image (x0 + (j + ½)·sx − ½, y0 + (i + ½)·sy − ½)."""
        return np.array([self.x0 + (p[0] + 0.5) * self.sx - 0.5, self.y0 + (p[1] + 0.5) * self.sy - 0.5])


def search_window(img: np.ndarray, roi_in: RoiLike) -> SearchWindow | Detection:
    """Search window (ROI bounding box grown by the margin), its downscales, exposure check, ROI
    mask and soil white balance; Detection "bad_image" when the frame or roi is not usable."""
    bad = Detection(None, 0.0, "bad_image")
    if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        return bad
    H, W = img.shape[:2]
    if H < 16 or W < 16:
        return bad
    try:
        roi = as_roi(roi_in, (H, W))
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
    sat = float(np.count_nonzero(cv2.min(cv2.min(b_, g_), r_) >= CLIP_LEVEL)) / gray.size  # clipped to white
    # (flat: also no pixel off by FLAT_RANGE, which a plant of a few grid pixels is, however small)
    flat = std < 1.5 and int(np.ptp(small.reshape(-1, 3), axis=0).max()) < FLAT_RANGE
    # no colour anywhere (a monochrome camera or stream, a grey-level file): greenness cannot be
    # judged, and "no_plant" would tell the operator there is no weed rather than no colour
    mono = max(cv2.norm(b_, g_, cv2.NORM_INF), cv2.norm(g_, r_, cv2.NORM_INF)) <= MONO_CHROMA
    if mean < 12 or sat > 0.6 or flat or mono or mean > 245:
        return bad
    noise = chroma_noise(crop)
    if max(_pixel_noise(crop), noise) >= NOISE_SIGMA and _coherence(mid) < NOISE_COHERENCE:  # (cheaper tests first)
        # strong noise, not a scene (a faulty sensor or a corrupted stream): max-pooled, it looks
        # green. Weak noise on a flat soil has no structure either, but a leaf as bright as the
        # soil is structure in colour only: such a frame is read, not rejected. (Noise independent in
        # each channel is √3 × its grey level's: its colour noise is asked too)
        return bad
    # the index image's own noise: area resampling by f × f averages the window's (a large plant
    # photographed at high resolution has thin petioles that a filter at that scale would erase)
    noise /= math.sqrt(crop.shape[0] * crop.shape[1] / (mid.shape[0] * mid.shape[1]))
    if noise > DENOISE_FROM:
        # heavy sensor noise (dim light, high gain): max-pooled, the index of a noisy soil has
        # specks as green as a seedling. A median filter of the index image removes them and
        # keeps edges (how often it runs, and what it moved: DENOISE_FROM)
        mid = cv2.medianBlur(mid, 3 if noise < 2 * DENOISE_FROM else 5)
        small = resize_down(mid, (small.shape[1], small.shape[0])) if mid.shape[:2] != small.shape[:2] else mid

    inside = np.ones(gray.shape, bool)
    if roi is not None:
        inside = roi_mask(roi, gray.shape, x0, y0, sx, sy)
    n_in = int(np.count_nonzero(inside))
    if roi is not None and n_in < 16:
        return bad
    # over-exposed soil: white balance and soil statistics from the unclipped pixels (`soil`), and the
    # clipped pixels' index capped (`clipped`, read by the looks and stage 2)
    clipped = unclipped(small) == 0
    n_clip = int(np.count_nonzero(clipped & inside))
    if n_clip < SOIL_CLIPPED * n_in:
        return SearchWindow(roi, x0, y0, x1, y1, mid, small, sx, sy, inside, n_in, soil_gains(small, inside), noise=noise)
    soil = inside & ~clipped if n_in - n_clip >= max(256, 0.1 * n_in) else None
    return SearchWindow(roi, x0, y0, x1, y1, mid, small, sx, sy, inside, n_in, soil_gains(small, inside if soil is None else soil),
                        soil=soil, noise=noise, clipped=clipped)


MONO_CHROMA = 0  # grey levels: largest |B − G| and |G − R| on the stage-1 grid of a frame without colour: grey
# frames, grey JPEGs decoded to BGR and mono YUV streams have exactly equal channels. Measured (session 69): bench
# seeds 0–11, 20–23, 30–37 ≥ 3 (7 200 frames; 3 and 6 on two dim ones, mean grey 29–40, the 3 a bare soil;
# median 82); field photos ≥ 38, in the photographer's shadow, bare ≥ 22; other renderer ≥ 21; photo-like ≥ 27;
# stones on soils ≥ 27
FLAT_RANGE = 16  # grey levels: a blank frame under sensor noise σ ≤ 5 stays within it on the stage-1 grid
NOISE_COHERENCE = 0.65  # measured: bench, photo-like and other-renderer frames ≥ 0.87; RGB noise ≤ 0.56
NOISE_SIGMA = 24.0  # grey levels of pixel noise (`_pixel_noise` of the grey level, or the colour noise,
# `chroma_noise`) from which an incoherent frame is noise: uniform RGB noise ≈ 50 / 77, Gaussian σ = 40 per
# channel ≈ 27 / 40 (JPEG-compressed uniform noise ≈ 51–54 grey); a flat soil under σ = 20 ≈ 13 / 20 is
# read; ±45 uniform noise round mid-grey (18 / 27) gave small ROIs a "plant" before its colour counted
DENOISE_FROM = 6.0  # σ of the index image's colour noise (`chroma_noise` of the window ÷ the resampling factor)
# above which that image is median-filtered (3 × 3; 5 × 5 from twice that). Measured (session 44), bench
# frames as rendered (seed 0): median 1.2, p99 5.3, max 6.8 (1 of 300 filtered); with Gaussian noise of
# σ = 8 added to every channel ≥ 5.2 (271 of 300 filtered). Bench seeds 0–7 as rendered: 5 answers moved by > 1 mm (1 better; a clover 1.6 → 22.3 mm,
# seed 3's p90 9.64 → 9.91 mm), pooled figures unchanged. Seeds 0–3 and 5 (1 275 weed, 225 bare frames)
# with noise added: σ = 8, wrong 58 → 42, p90 16.9 → 15.1 mm, bare soil answered 10 → 12; σ = 15, wrong
# 83 → 52, p90 22.6 → 20.2 mm, found 1 232 → 1 228, bare soil answered 33 → 15 (as rendered: 22 wrong, 6
# bare answered). Field photos (bench/field_photo_weeds.py: luminance noise and blotchy chroma, as a
# camera leaves them) measure ≤ 0.9 (1 260 photos): none filtered, none moved. Gated on each channel's noise instead
# (luminance noise counted), a fifth of them were: 8 fewer found.


NOISE_ROWS = 16  # rows sampled by `chroma_noise` (~11 000 differences a colour pair on a bench window)


def chroma_noise(bgr: np.ndarray, rows: int = NOISE_ROWS) -> float:
    """Pixel-scale colour noise, as the σ of independent noise in each channel, in grey levels: the
    median absolute second difference of G − B and of G − R along `rows` rows spread over the image
    (the larger), / (0.6745 · √12) (Gaussian noise; the median, unlike the mean, ignores edges and
    texture). Noise equal in all channels (the luminance noise a camera leaves after its chroma
    denoising) cancels, as it does in the vegetation index. ~0.12 ms on a 700 × 600 window."""
    step = max(1, bgr.shape[0] // rows)
    sample = bgr[step // 2::step]
    if sample.shape[0] == 0 or sample.shape[1] < 3:
        return 0.0
    g = sample[..., 1].astype(np.int16)
    out = 0.0
    for other in (0, 2):  # G − B, G − R
        c = g - sample[..., other]
        d = np.minimum(np.abs(c[:, :-2] - 2 * c[:, 1:-1] + c[:, 2:]).ravel(), 2047)
        h = np.bincount(d, minlength=2048)
        cdf = np.cumsum(h)
        half = cdf[-1] / 2
        k = int(np.searchsorted(cdf, half))
        out = max(out, k - 0.5 + (half - (cdf[k - 1] if k else 0.0)) / max(h[k], 1.0))  # median, within its bin
    return max(out, 0.0) / (0.6745 * math.sqrt(12.0))


def _pixel_noise(bgr: np.ndarray) -> float:
    """Pixel-scale noise σ of the grey level, in grey levels, from the mean absolute difference of
    horizontal neighbours on every 8th row (σ = E|d|·√π / 2 for Gaussian noise). A scene's edges
    add to it too, so a frame is noise only if it also lacks structure (`_coherence`), which is
    asked second: bench frames measure 3–6 here, and this test costs less."""
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
