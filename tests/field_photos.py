"""bench/field_photo_weeds.py (an independent photo renderer) loaded as a module for tests, and
the distance of an answer from its crown."""

from __future__ import annotations

import functools
import importlib.util
import math
import sys
from pathlib import Path


@functools.cache
def field_photos():
    """The module (bench/ is not a package; its dataclasses need it in sys.modules while it loads)."""
    path = Path(__file__).resolve().parents[1] / "bench" / "field_photo_weeds.py"
    spec = importlib.util.spec_from_file_location("field_photo_weeds", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def crown_off(det, truth, S: float) -> float:
    """How far a Detection's answer lies from the crown `truth` (u, v), in S (the plant's visible
    diameter); ∞ when there is no answer (a reason, or no pixel)."""
    if det.reason is not None or det.pixel is None:
        return float("inf")
    return math.hypot(det.pixel[0] - truth[0], det.pixel[1] - truth[1]) / S
