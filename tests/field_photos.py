"""The independent renderers of bench/ (bench/field_photo_weeds.py, bench/other_renderer_plants.py) loaded
as modules for tests, and the distance of an answer from its crown."""

from __future__ import annotations

import functools
import importlib.util
import math
import sys
from pathlib import Path


@functools.cache
def bench_module(name: str):
    """bench/<name>.py as a module (bench/ is not a package; dataclasses need the module in
    sys.modules while it loads)."""
    path = Path(__file__).resolve().parents[1] / "bench" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def field_photos():
    """bench/field_photo_weeds.py, the field-photo renderer."""
    return bench_module("field_photo_weeds")


def crown_off(det, truth, S: float) -> float:
    """How far a Detection's answer lies from the crown `truth` (u, v), in S (the plant's visible
    diameter); ∞ when there is no answer (a reason, or no pixel)."""
    if det.reason is not None or det.pixel is None:
        return float("inf")
    return math.hypot(det.pixel[0] - truth[0], det.pixel[1] - truth[1]) / S
