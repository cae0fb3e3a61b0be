"""What the weed-centre detector answers (`Detection`), and the MPOI X̄_w on the ground from it.

Its own module so that the detector's stages (`capm_field.search_window`,
`capm_field.plant_choice`, `capm_field.detector`) can all answer with it without importing
one another in a circle.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from .camera import PinholeCamera

Reason = Literal["no_plant", "ambiguous", "cut_by_border", "bad_image"]


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
