"""Polling helper shared by the tests that wait on threads, sessions or a bus."""

from __future__ import annotations

import time
from typing import Callable


def wait_for(pred: Callable[[], object], timeout: float = 3.0, step: float = 0.01) -> bool:
    """Poll `pred` every `step` s until it holds or `timeout` s pass; its last value, as a bool."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(step)
    return bool(pred())
