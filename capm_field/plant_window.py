"""The full-resolution window round a stage-2 plant that the stalk estimators work in.

Stage 2 (`capm_field.centre_cascade`) locates a plant on a grid of ~80 px across; stalks and
petioles are 1–3 image pixels wide, so `capm_field.stalks` and `capm_field.hub_petioles` look at
the image itself, at its own pitch (coarser only beyond `max_px`), in a window reaching `margin` ×
the plant's window round it (a clover's centre may lie outside the leaves stage 1 grouped).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .vegetation import resize_down


@dataclass
class PlantWindow:
    """The image window (xa, ya) … at pitch (p_x, p_y) image px; stage-2 grid pixel (j, i) is image
    (X0 + (j + 0.5)·kx − 0.5, Y0 + (i + 0.5)·ky − 0.5), window pixel x is image xa + (x + 0.5)·p_x − 0.5."""

    region: np.ndarray  # the window's BGR pixels on its grid
    xa: int
    ya: int
    p_x: float
    p_y: float
    X0: int
    Y0: int
    kx: float
    ky: float

    def mask(self, m: np.ndarray) -> np.ndarray:
        """A stage-2 grid mask on the window's grid (nearest pixel)."""
        M = np.array([[self.p_x / self.kx, 0, (self.xa - self.X0 + 0.5 * self.p_x) / self.kx - 0.5],
                      [0, self.p_y / self.ky, (self.ya - self.Y0 + 0.5 * self.p_y) / self.ky - 0.5]], np.float32)
        h, w = self.region.shape[:2]
        return cv2.warpAffine(m.astype(np.uint8), M, (w, h), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_CONSTANT) > 0

    def from_stage2(self, q: np.ndarray) -> np.ndarray:
        """Stage-2 grid points (…, 2) → window grid points."""
        x, y = self.X0 + (q[..., 0] + 0.5) * self.kx - 0.5, self.Y0 + (q[..., 1] + 0.5) * self.ky - 0.5
        return np.stack([(x - self.xa + 0.5) / self.p_x - 0.5, (y - self.ya + 0.5) / self.p_y - 0.5], -1)

    def to_stage2(self, X: np.ndarray) -> np.ndarray:
        """A window grid point (x, y) → the stage-2 grid."""
        x, y = self.xa + (X[0] + 0.5) * self.p_x - 0.5, self.ya + (X[1] + 0.5) * self.p_y - 0.5
        return np.array([(x - self.X0 + 0.5) / self.kx - 0.5, (y - self.Y0 + 0.5) / self.ky - 0.5])


def plant_window(img: np.ndarray, X0: int, Y0: int, kx: float, ky: float, shape: tuple[int, int],
                 max_px: int, margin: float) -> PlantWindow | None:
    """The window round the stage-2 plant grid of `shape` (h, w) whose pixel (0, 0) is image (X0, Y0)
    at pitch (kx, ky): `margin` × the plant window round it, clipped to the image, at the image's pitch
    or coarser so that the plant window is ≤ `max_px` across. None when the window is under 16 px."""
    nh, nw = shape
    H, W = img.shape[:2]
    span = max(nw * kx, nh * ky)  # the stage-2 window in image pixels
    p = max(1.0, span / max_px)  # pitch of the window's grid, image pixels
    m = margin * span
    xa, ya = max(int(math.floor(X0 - m)), 0), max(int(math.floor(Y0 - m)), 0)
    xb, yb = min(int(math.ceil(X0 + nw * kx + m)), W), min(int(math.ceil(Y0 + nh * ky + m)), H)
    if xb - xa < 16 or yb - ya < 16:
        return None
    NW, NH = max(int((xb - xa) / p), 8), max(int((yb - ya) / p), 8)
    region = resize_down(img[ya:yb, xa:xb], (NW, NH)) if p > 1.0 else img[ya:yb, xa:xb]
    return PlantWindow(region, xa, ya, (xb - xa) / region.shape[1], (yb - ya) / region.shape[0], X0, Y0, kx, ky)
