"""Vegetation index images for the weed detector: soil-referenced white balance, G* and CIELAB
−a*, and the max-pooled index on a coarser grid that keeps thin blades and stalks.

Stage 1 (find the plant) and stage 2 (find its centre) of `capm_field.detector` both work on
these; the resampling helpers keep OpenCV on its fast paths (see `resize_down`).
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np

from .compiled import kernel
from .order_stats import median, row_medians

SOIL_REF = np.array([0.27, 0.33, 0.40], np.float32)  # typical soil chromaticity (B, G, R)


def soil_gains(bgr: np.ndarray, inside: np.ndarray | None = None) -> np.ndarray:
    """Per-channel gains mapping the scene's soil to a typical soil colour (von Kries).

    The soil reference is the median colour of the less-green half of the pixels, so a colour
    cast of the light or the camera's white balance is removed before judging greenness. Gains
    are bounded (GAIN_MIN..GAIN_MAX) so a frame filled with leaves cannot be "corrected" into soil
    and a yellow or red soil is not made grey. (On an over-exposed soil the caller leaves the
    clipped pixels out of `inside`: their colour is not the soil's; `search_window`.)
    """
    # a sample of ~20 000 pixels is enough for medians: stride the grid before masking
    k = max(1, int(math.sqrt(bgr.shape[0] * bgr.shape[1] / 20000)))
    sub = bgr[::k, ::k]
    # rows picked by index (`take`): the same pixels as a boolean mask over (h, w, 3), ~2× faster
    px = np.ascontiguousarray(sub).reshape(-1, 3)
    f = (px if inside is None else px.take(np.flatnonzero(inside[::k, ::k]), axis=0)).astype(np.float32)
    gs = greenness(f[None])[0]
    soil = f.take(np.flatnonzero(gs <= median(gs)), axis=0)
    ref = row_medians(np.ascontiguousarray(soil.T)) + 1.0
    g = SOIL_REF / (ref / ref.sum())
    return np.clip((g / g[1]) ** WB_STRENGTH, GAIN_MIN, GAIN_MAX).astype(np.float32)


WB_STRENGTH = 1.0  # exponent on the gains (0.5, 0.75 measured: no better)
# gain bounds: enough for a light or camera colour cast; a soil that is itself yellow (sand,
# straw) or red keeps most of its colour, else its "correction" turns a dark green leaf grey-
# blue (0.6–1.6 lost 4 of 100 rosettes on yellow soils in bench/other_renderer_rosettes.py;
# bench seeds 0–3 unchanged within ±1 case)
GAIN_MIN, GAIN_MAX = 0.8, 1.25


def greenness(bgr: np.ndarray) -> np.ndarray:
    """G* = (G − max(R, B)) / (B + G + R + 30): positive only where green dominates.

    Live leaves reflect green more than red and blue; soil, stones, straw and dead leaves do not.
    The +30 keeps sensor noise in dark shadows from looking green.
    """
    f = bgr if bgr.dtype == np.float32 else bgr.astype(np.float32)
    if f.ndim == 3 and f.shape[2] == 3 and f.flags.c_contiguous:
        b, g, r = cv2.split(f)  # copies: `_gstar` may overwrite them
    else:
        b, g, r = (np.ascontiguousarray(f[..., k]) for k in range(3))
    return _gstar(b, g, r)


def _gstar(b: np.ndarray, g: np.ndarray, r: np.ndarray) -> np.ndarray:
    """G* of float32 planes, computed in place (b and r are overwritten): a fresh full-size float
    image can cost more in page faults (~2 µs per 4 kB page on the VM) than the arithmetic."""
    num = cv2.max(r, b)
    cv2.subtract(g, num, dst=num)  # G − max(R, B)
    cv2.add(b, g, dst=b)
    np.add(r, np.float32(30.0), out=r)  # (cv2.add would read 30.0 as a 4 × 1 array beside a 4 × 1 plane)
    cv2.add(b, r, dst=b)  # (B + G) + (R + 30)
    return cv2.divide(num, b, dst=num)


def vegetation_index(bgr: np.ndarray, inside: np.ndarray | None = None, gains: np.ndarray | None = None,
                     lab: bool = False) -> np.ndarray:
    """Greenness after soil-referenced white balance (see `soil_gains`), float32 (h, w).

    lab=False: G* (`greenness`). lab=True: −a*/100 of CIELAB, the green–red opponent axis, which
    also ranks yellow-green leaves (G ≈ R) above soil and straw; used by the second look only.
    """
    if gains is None:
        gains = soil_gains(bgr, inside)
    if lab:
        return neg_a_star(bgr, gains)
    if bgr.dtype == np.uint8 and bgr.ndim == 3 and bgr.shape[2] == 3:
        tabs = _gain_tables(tuple(float(k) for k in np.asarray(gains).reshape(3)))
        if _gstar_u8 is not None:
            return _gstar_u8(bgr, tabs)
        # (without the compiled loop: the planes split and scaled by table lookup, the same values)
        return _gstar(*(cv2.LUT(p, t.reshape(256, 1)) for p, t in zip(cv2.split(np.ascontiguousarray(bgr)), tabs)))
    return greenness(_scaled(bgr, gains))


@functools.lru_cache(maxsize=16)
def _gain_tables(gains: tuple[float, float, float]) -> np.ndarray:
    """(3, 256) float32, read-only: per channel (B, G, R), the value of each 8-bit level × its gain,
    as `cv2.multiply(plane, gain, dtype=CV_32F)` gives it."""
    levels = np.arange(256, dtype=np.uint8).reshape(256, 1)
    t = np.stack([cv2.multiply(levels, k, dtype=cv2.CV_32F).ravel() for k in gains])
    t.flags.writeable = False
    return t


@kernel(lambda nb: nb.float32[:, ::1](nb.types.Array(nb.uint8, 3, "A", readonly=True),
                                     nb.types.Array(nb.float32, 2, "C", readonly=True)))
def _gstar_u8(bgr, tabs):  # pragma: no cover - compiled; tested against the float path in tests/test_vegetation_index.py
    """G* of an 8-bit BGR image (any strides) whose channels are scaled by table lookup (`_gain_tables`).

    One pass per pixel (`capm_field.compiled`), the float32 operations of `_gstar` in its order,
    so the same values to the last bit: 0.35 against 0.82 ms for 250 000 px (OpenCV's split, three
    lookups and five full-image operations, each a pass over memory; session 41)."""
    h, w = bgr.shape[0], bgr.shape[1]
    out = np.empty((h, w), np.float32)
    c30 = np.float32(30.0)
    for i in range(h):
        for j in range(w):
            b, g, r = tabs[0, bgr[i, j, 0]], tabs[1, bgr[i, j, 1]], tabs[2, bgr[i, j, 2]]
            m = r if r > b else b  # max(R, B)
            out[i, j] = (g - m) / ((b + g) + (r + c30))
    return out


def neg_a_star(bgr: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """−a*/100 of CIELAB (D65, sRGB) of `bgr` × per-channel `gains` (on 0–255, clipped to white),
    float32 (h, w), from CIE's own formulas.

    a* = 500 (f(X/Xn) − f(Y)), f(t) = ∛t above (6/29)³, else t/(3 (6/29)²) + 4/29, with X and Y
    linear in the linearised sRGB channels. Each channel's gain, clipping and sRGB linearisation
    is one 256-entry table for 8-bit input, so only two channel sums and two cube roots (`_cie_f`) are
    left: 1.2–1.5 ms for a 0.25 MP image against 2.5–4 ms for OpenCV's float Lab conversion (the same
    frames, session 34, idle and loaded VM), which is also approximate (OpenCV 5.0: its
    linearisation is up to 0.4 % off, −a*/100 up to 0.007, and it changes with OpenCV's version).
    """
    g = np.asarray(gains, np.float64).reshape(3)
    if bgr.dtype == np.uint8 and bgr.ndim == 3 and bgr.shape[2] == 3:
        lin = cv2.LUT(bgr, _linear_table(tuple(g.tolist())))
        x = cv2.transform(lin, _XN_BGR)
        y = cv2.transform(lin, _Y_BGR)
    else:
        lin = _srgb_linear(np.asarray(bgr, np.float64) * (g / 255.0))
        x, y = (np.ascontiguousarray((lin @ m.ravel()).astype(np.float32)) for m in (_XN_BGR, _Y_BGR))
    fx, fy = _cie_f(x), _cie_f(y)
    cv2.subtract(fy, fx, dst=fy)
    return cv2.multiply(fy, 5.0, dst=fy)


@functools.lru_cache(maxsize=8)
def _linear_table(gains: tuple[float, float, float]) -> np.ndarray:
    """(256, 1, 3) float32, read-only: each 8-bit value × its channel's gain, as linear light. One look
    asks for it with the same gains for the window, every candidate and stage 2 (~15 µs to make)."""
    t = _srgb_linear(np.arange(256.0)[:, None] * (np.array(gains) / 255.0)).astype(np.float32).reshape(256, 1, 3)
    t.flags.writeable = False
    return t


def _srgb_linear(c: np.ndarray) -> np.ndarray:
    """sRGB value (0..1, clipped) → linear light (IEC 61966-2-1)."""
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _cie_f(t: np.ndarray) -> np.ndarray:
    """CIELAB's f, in place on float32 `t`: ∛t above (6/29)³, else t/(3 (6/29)²) + 4/29.

    The cube root is OpenCV's vectorised pow (within 2 ulp of `np.cbrt`, 1.8e-7 at most on 0..1):
    ~0.4 ms for 0.3 MP against 4.5 ms for `np.cbrt`, a libm call per element (session 60; it was
    an eighth of the detector's time on bench seed 0)."""
    lo = float(t.min()) <= _CIE_EPS if t.size else False
    low = t <= _CIE_EPS if lo else None
    lin = t * np.float32(1.0 / (3 * (6 / 29) ** 2)) + np.float32(4 / 29) if lo else None
    if t.size:
        cv2.pow(t, 1.0 / 3.0, dst=t)
    if lo:
        np.copyto(t, lin, where=low)
    return t


_CIE_EPS = (6 / 29) ** 3
# sRGB → XYZ (D65) rows for X/Xn and Y, columns in B, G, R order (cv2.transform's 1 × 3 matrices)
_XN_BGR = (np.array([[0.180423, 0.357580, 0.412453]]) / 0.950456).astype(np.float32)
_Y_BGR = np.array([[0.072169, 0.715160, 0.212671]], np.float32)


def _scaled(bgr: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """float32 bgr × per-channel gains (OpenCV: ~4× faster than numpy's cast and multiply)."""
    if bgr.ndim != 3 or bgr.shape[2] != 3:
        return bgr.astype(np.float32) * gains
    return cv2.multiply(bgr, (float(gains[0]), float(gains[1]), float(gains[2]), 0.0), dtype=cv2.CV_32F)


def resize_down(src: np.ndarray, size: tuple[int, int], exact: bool = False) -> np.ndarray:
    """`src` area-resampled down to `size` (w, h), by OpenCV's fast paths.

    cv2.INTER_AREA at a non-integer ratio takes a slow general path (2–3 ms for a 0.3 MP window,
    a tenth of the frame budget); at an exact integer ratio it is a fast box average. So a ratio
    r ≥ AREA_MIN_RATIO is done as a bilinear resampling to k × `size`, k = max(2, ⌊r⌋) (a ratio
    r/k within [0.75, 1.5)), followed by the k × k box average: every source pixel keeps a
    weight, thin stems are not skipped (mean difference to INTER_AREA ≈ 0.1–0.2 grey levels).
    Below it, bilinear resampling (after a light blur, see below) touches every source pixel.
    Stage 1 of a bench frame: −1.8 ms median latency (paired, seed 0); the benches moved by
    their resampling noise (seeds 0–3: wrong centres 29 → 28, detections 996 → 994 of 1020).
    exact=True: plain INTER_AREA, for stage 2 (the plant crop, where the centre is located; the
    fast path saved no measurable time there).
    """
    nw, nh = size
    h, w = src.shape[:2]
    if (nw, nh) == (w, h):
        return src
    if exact:
        return cv2.resize(src, (nw, nh), interpolation=cv2.INTER_AREA)
    r = min(w / nw, h / nh)
    if r < AREA_MIN_RATIO:
        # bilinear alone averages less than the area filter where samples fall on pixel centres:
        # the soil's noise would rise (and so the 5 σ threshold); a 3 × 3 Gaussian of σ = 0.3 r
        # restores INTER_AREA's noise level within ~5 %
        return cv2.resize(cv2.GaussianBlur(src, (3, 3), 0.3 * r), (nw, nh), interpolation=cv2.INTER_LINEAR)
    k = max(2, int(r))
    if (w, h) != (k * nw, k * nh):
        src = cv2.resize(src, (k * nw, k * nh), interpolation=cv2.INTER_LINEAR)
    return cv2.resize(src, (nw, nh), interpolation=cv2.INTER_AREA)


AREA_MIN_RATIO = 1.5  # downscale ratio from which `resize_down` box-averages


def downscale(bgr: np.ndarray, max_px: int, exact: bool = False) -> np.ndarray:
    """`bgr` itself if it has at most `max_px` pixels, else area-resampled down to that many."""
    h, w = bgr.shape[:2]
    g = max(1.0, math.sqrt(h * w / max_px))
    if g <= 1.0:
        return bgr
    return resize_down(bgr, (max(1, round(w / g)), max(1, round(h / g))), exact)


# Over-exposure. Where red or blue is clipped their true level is higher than recorded, so G* and −a*
# (both fall as red or blue rises) are upper bounds only; white balance gains < 1 turn clipped white
# or yellow soil green. On bench soils that are over-exposed (sand in the sun: 20–50 % of the window
# clipped) those pixels spread the soil's index and push the threshold over an olive or yellow-green
# weed; on photos with a few clipped highlights (≤ 2 % of the frame, often on the leaves themselves)
# nothing is changed. (Session 47: bench seeds 0–7 and field photos; docs/perception.md §2.)
CLIP_LEVEL = 250  # an 8-bit channel at or above this is taken as clipped
SOIL_CLIPPED = 0.1  # share of the window with red or blue clipped from which the soil is over-exposed


def unclipped(bgr: np.ndarray) -> np.ndarray:
    """uint8 mask of a BGR image: 255 where neither red nor blue reaches CLIP_LEVEL."""
    return cv2.inRange(bgr, (0, 0, 0), (CLIP_LEVEL - 1, 255, CLIP_LEVEL - 1))


def cap_clipped(bgr: np.ndarray, vi: np.ndarray, level: float | None = None) -> None:
    """Cap the index `vi` of `bgr` (same shape) at `level` where red or blue is clipped (an upper
    bound there), in place. `level` None: the median index of the unclipped pixels."""
    ok = unclipped(bgr)
    n_ok = cv2.countNonZero(ok)
    if n_ok == ok.size or (level is None and n_ok == 0):
        return
    if level is None:
        level = float(median(vi[ok > 0]))
    bad = ok == 0
    vi[bad] = np.minimum(vi[bad], np.float32(level))


def pooled_index(bgr: np.ndarray, gains: np.ndarray, size: tuple[int, int], mid_px: int, lab: bool = False,
                 exact: bool = False, cap: bool = False, cap_level: float | None = None) -> np.ndarray:
    """Vegetation index of `bgr` on a coarser grid `size` (w, h), thin parts kept (max-pooling).

    Averaging colours before judging greenness dilutes 1–2 px stems, petioles and grass blades
    into the soil. The index is computed at an intermediate resolution (the input itself if it
    has at most `mid_px` pixels, else downscaled to that), lightly smoothed against sensor noise,
    then max-pooled (grey dilation over one output cell, then area resampling) to `size`.
    `cap`: the index of clipped pixels is capped first (`cap_clipped`, at `cap_level`).
    """
    nw, nh = size
    mid = downscale(bgr, mid_px, exact)
    vi = vegetation_index(mid, gains=gains, lab=lab)
    if cap:
        cap_clipped(mid, vi, cap_level)
    # blur and dilate in place (same values): no further full-size temporaries
    cv2.GaussianBlur(vi, (0, 0), 0.7, dst=vi)
    f = mid.shape[1] / nw
    if f <= 1.25:
        return cv2.resize(vi, (nw, nh), interpolation=cv2.INTER_LINEAR) if (nw, nh) != (mid.shape[1], mid.shape[0]) else vi
    k = int(round(f))
    cv2.dilate(vi, np.ones((k, k), np.uint8), dst=vi)
    return resize_down(vi, (nw, nh), exact)
