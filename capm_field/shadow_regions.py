"""Lit and shadowed parts of a search window split by a large cast shadow.

A person's or a crop row's shadow puts two soils into one frame: the shadowed soil is darker,
bluer (sky light) and noisier in the index than the sunlit one. One soil threshold over both
(`capm_field.vegetation_mask.threshold`: median + 5 σ) gets σ from the mixture, up to three
times what either soil alone measures, so a pale plant in either part stays under it. The
detector (`capm_field.detector`) looks again in each part on its own, with that part's white
balance and soil statistics, when the whole window found no plant.
"""

from __future__ import annotations

import math
import warnings

import cv2
import numpy as np
from scipy import ndimage

from .vegetation import greenness

SHADOW_CELLS = 16  # cells along the window's longer side: the soil's brightness is mapped per cell
SHADOW_SOIL_G = 0.0  # G* (raw colours) at most of a soil pixel: plants and their leaves are left out
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
    bgr = np.ascontiguousarray(bgr)
    soil = inside & (greenness(bgr) <= SHADOW_SOIL_G)
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(np.float32)
    lg = np.where(soil, np.log(grey + 8.0), np.nan)
    cs = int(math.ceil(max(h, w) / SHADOW_CELLS))
    ny, nx = -(-h // cs), -(-w // cs)
    pad = np.full((ny * cs, nx * cs), np.nan, np.float32)
    pad[:h, :w] = lg
    blocks = pad.reshape(ny, cs, nx, cs).transpose(0, 2, 1, 3).reshape(ny, nx, cs * cs)
    n_soil = np.count_nonzero(~np.isnan(blocks), axis=2)
    valid = n_soil >= SHADOW_CELL_SOIL * cs * cs
    if np.count_nonzero(valid) < 8:
        return []
    with warnings.catch_warnings():  # cells without soil are all-NaN: filled below
        warnings.simplefilter("ignore", RuntimeWarning)
        cell = np.nanmedian(blocks, axis=2)
    v = np.sort(cell[valid])
    t, eta = _otsu(v)
    dark, lit = v[v <= t], v[v > t]
    if min(len(dark), len(lit)) < SHADOW_SHARE * len(v) or eta < SHADOW_SEP:
        return []
    if float(np.median(lit)) - float(np.median(dark)) < math.log(SHADOW_RATIO):
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
