"""bench/field_photo_weeds.py (an independent photo renderer) loaded as a module for tests."""

from __future__ import annotations

import functools
import importlib.util
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
