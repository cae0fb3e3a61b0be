"""Connected components of binary masks, by OpenCV's fastest labelling with statistics.

`cv2.connectedComponentsWithStats` defaults to the Spaghetti algorithm, whose statistics pass
costs ~1.8× that of Grana's block-based labelling (OpenCV 5.0, one thread: 0.57 vs 0.31 ms on a
320 × 320 stage-1 mask). Labels, statistics and centroids are the same (both number the
components in raster order of their first pixel); the detector labels ~6 masks a frame.
"""

from __future__ import annotations

import cv2
import numpy as np


def components(mask: np.ndarray) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """8-connected components of `mask` (bool or uint8): (count incl. background, int32 labels,
    stats (CC_STAT_* columns), centroids) exactly as `cv2.connectedComponentsWithStats(…, 8)`."""
    m = mask if mask.dtype == np.uint8 else mask.astype(np.uint8)
    return cv2.connectedComponentsWithStatsWithAlgorithm(m, 8, cv2.CV_32S, cv2.CCL_GRANA)
