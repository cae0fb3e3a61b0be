"""Lit and shadowed parts of a search window split by a large cast shadow.

A person's or a crop row's shadow puts two soils into one frame: the shadowed soil is darker,
bluer (sky light) and noisier in the index than the sunlit one. One soil threshold over both
(`capm_field.vegetation_mask.threshold`: median + 5 σ) gets σ from the mixture, up to three
times what either soil alone measures, so a pale plant in either part stays under it. The
detector (`capm_field.detector`) looks again in each part on its own, with that part's white
balance and soil statistics, after the whole window's looks (whether they found a plant or not).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy import ndimage

from .order_stats import median, percentile

SHADOW_CELLS = 16  # cells along the window's longer side: the soil's brightness is mapped per cell
SHADOW_STEP = 2  # the map is measured on every this-th pixel in each direction
SHADOW_CELL_SOIL = 0.25  # a cell's least share of soil pixels to be measured (else filled from its neighbours)
SHADOW_RATIO = 1.5  # lit / shadow brightness (medians of the two classes of cells) for a cast shadow
SHADOW_SHARE = 0.15  # each part's least share of the measured cells
SHADOW_SEP = 0.75  # Otsu separability η of the cells' log brightness (between-class / total variance)


def shadow_regions(bgr: np.ndarray, inside: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(lit, its core), (shadowed, its core)] masks within `inside` when a large cast shadow splits
    the window, else []. A core is its part without a band of half a cell along the boundary.

    The soil's brightness is mapped on a grid of cells (median log grey of each cell's soil
    pixels: not green, inside), ignoring plants and anything smaller than a cell. A cast shadow
    splits the cells into two classes (Otsu) SHADOW_RATIO apart, each ≥ SHADOW_SHARE of them,
    well separated (η ≥ SHADOW_SEP): mottled or cracked soil, stones and straw are not. The
    boundary follows the cell map interpolated to pixels; cells covered by a plant take the
    brightness of the nearest measured cell.
    """
    h, w = bgr.shape[:2]
    n_in = int(np.count_nonzero(inside))
    if min(h, w) < 32 or n_in < 1024:
        return []
    cs = int(math.ceil(max(h, w) / SHADOW_CELLS))
    ny, nx = -(-h // cs), -(-w // cs)
    if not _may_split(bgr, inside, nx, ny):
        return []
    # the map is measured on every SHADOW_STEP-th pixel in each direction (≥ 100 in a cell of a
    # 320-px window): a cast shadow spans cells, and the detector asks this of most frames
    sub = np.ascontiguousarray(bgr[::SHADOW_STEP, ::SHADOW_STEP])
    # soil: not green in the camera's colours, G* ≤ 0 (`vegetation.greenness`), i.e. G ≤ max(R, B)
    # (G*'s denominator is positive), tested on the 8-bit planes: plants and leaves are left out
    b, g, r = cv2.split(sub)
    soil = inside[::SHADOW_STEP, ::SHADOW_STEP] & (g <= cv2.max(b, r))
    grey = cv2.cvtColor(sub, cv2.COLOR_BGR2GRAY)
    cell, n_soil = _cell_medians(grey, soil, cs, ny, nx, SHADOW_STEP)
    valid = n_soil >= SHADOW_CELL_SOIL * (cs / SHADOW_STEP) ** 2
    if np.count_nonzero(valid) < 8:
        return []
    v = np.sort(cell[valid])
    t, eta = _otsu(v)
    dark, lit = v[v <= t], v[v > t]
    if min(len(dark), len(lit)) < SHADOW_SHARE * len(v) or eta < SHADOW_SEP:
        return []
    if median(lit) - median(dark) < math.log(SHADOW_RATIO):
        return []
    # cells without enough soil (a plant, the ROI's outside) take the nearest measured cell's value
    idx = ndimage.distance_transform_edt(~valid, return_distances=False, return_indices=True)
    cell = cell[idx[0], idx[1]].astype(np.float32)
    smooth = cv2.resize(cell, (nx * cs, ny * cs), interpolation=cv2.INTER_LINEAR)[:h, :w]
    # each part's soil statistics leave out the penumbra and the boundary's uncertainty of about
    # half a cell: that soil is between the two, and would widen either part's spread
    shadow = (smooth <= t).astype(np.uint8)
    band = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (cs | 1, cs | 1))
    lit_core, shadow_core = cv2.erode(1 - shadow, band).astype(bool), cv2.erode(shadow, band).astype(bool)
    return [(inside & (shadow == 0), inside & lit_core), (inside & (shadow == 1), inside & shadow_core)]


def _may_split(bgr: np.ndarray, inside: np.ndarray, nx: int, ny: int) -> bool:
    """A cheap first test (~0.06 ms, on every 4th pixel): whether the cells' mean log grey, plants
    included, spreads by ≥ SHADOW_SPREAD between its 15th and 85th percentiles (cells at least half
    inside). Windows that a cast shadow splits measured ≥ 0.385 (920 windows: bench seed 0,
    field-photo seeds 0–2 and the photographer's-shadow sets); 42 % of bench windows pass."""
    sub = np.ascontiguousarray(bgr[::4, ::4])
    if min(sub.shape[:2]) < 2:
        return True
    g = cv2.resize(cv2.cvtColor(sub, cv2.COLOR_BGR2GRAY).astype(np.float32), (nx, ny), interpolation=cv2.INTER_AREA)
    share = cv2.resize(inside[::4, ::4].astype(np.float32), (nx, ny), interpolation=cv2.INTER_AREA)
    v = np.log(g[share >= 0.5] + 8.0)
    if len(v) < 8:
        return True  # too few cells to tell: the full test decides
    lo, hi = percentile(v, (15, 85))
    return hi - lo >= SHADOW_SPREAD


SHADOW_SPREAD = 0.3  # log grey: the first test's least spread (a shadow needs log 1.5 ≈ 0.41 between its classes)
_LOG_GREY = np.log(np.arange(256, dtype=np.float32) + np.float32(8.0))  # log(grey + 8) per 8-bit level


def _cell_medians(grey: np.ndarray, soil: np.ndarray, cs: int, ny: int, nx: int,
                  step: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(median log(grey + 8) of the `soil` pixels of each cs × cs cell (NaN where none), their
    count), (ny, nx) each; `grey` and `soil` hold every `step`-th pixel of the window. From one
    histogram of the 8-bit grey per cell: the same medians as sorting each cell's log values (log
    is monotonic; an even count averages the two middle ones, in float32), without np.nanmedian's
    loop over the cells."""
    h, w = grey.shape
    cid = (np.arange(0, h * step, step) // cs)[:, None] * nx + (np.arange(0, w * step, step) // cs)[None, :]
    sel = soil.ravel()
    key = cid.ravel()[sel] * 256 + grey.ravel()[sel]  # cell, then grey level: one sort order
    c = np.cumsum(np.bincount(key, minlength=ny * nx * 256))
    n = np.diff(c[255::256], prepend=0)  # soil pixels per cell
    first = c[255::256] - n  # rank of each cell's first value in that order
    # the level of the value of rank r is the first bin whose cumulative count exceeds r
    lo = np.searchsorted(c, first + (n - 1) // 2, side="right") % 256
    hi = np.searchsorted(c, first + n // 2, side="right") % 256
    med = (_LOG_GREY[lo] + _LOG_GREY[hi]) / np.float32(2.0)
    med[n == 0] = np.nan
    return med.reshape(ny, nx), n.reshape(ny, nx)


def _otsu(v: np.ndarray) -> tuple[float, float]:
    """Otsu's split of sorted values: (threshold, separability η = between-class / total variance).
    Exact over ≤ SHADOW_CELLS² values (OpenCV's Otsu quantises to 256 levels and gives no η)."""
    n = len(v)
    c = np.cumsum(v)
    k = np.arange(1, n)  # the lower class is v[:k]
    m0 = c[:-1] / k
    m1 = (c[-1] - c[:-1]) / (n - k)
    between = (k / n) * (1 - k / n) * (m1 - m0) ** 2
    i = int(np.argmax(between))
    var = float(v.var())
    return float(0.5 * (v[i] + v[i + 1])), (float(between[i]) / var if var > 0 else 0.0)
