"""The detector's per-pixel loops compiled with numba, each with the numpy/OpenCV formulation it
replaced as the fallback.

A loop is compiled when its module is imported (explicit signature, so no first-frame compile;
cached beside the module, or in numba's user cache where that is read-only). Where numba is
missing or cannot compile (a platform without its wheels, an OS that refuses JIT memory),
`kernel` gives None and the caller runs the formulation the loop replaced: the same values,
~6 ms slower a frame (all four loops, session 45), and one warning in the log. A field run does not stop for a speed-up.
"""

from __future__ import annotations

import logging
from typing import Callable

log = logging.getLogger(__name__)

try:
    import numba
except Exception as exc:  # noqa: BLE001 - ImportError, or llvmlite failing to load its library
    numba = None
    _missing: Exception | None = exc
else:
    _missing = None


def kernel(signature: Callable[[object], object]) -> Callable[[Callable], Callable | None]:
    """Decorator: the function compiled by numba for `signature(numba)` (nopython, no GIL held,
    cached), or None, with a warning, if numba is missing or cannot compile it."""

    def wrap(fn: Callable) -> Callable | None:
        name = f"{fn.__module__}.{fn.__qualname__}"
        if numba is None:
            log.warning("numba is not available (%s): %s runs in numpy, slower", _missing, name)
            return None
        for cache in (True, False):  # (no writable cache directory: compiled anew in each process)
            try:
                return numba.njit(signature(numba), cache=cache, nogil=True)(fn)
            except Exception:  # noqa: BLE001 - any compile failure leaves the numpy formulation
                if not cache:
                    log.warning("numba could not compile %s: it runs in numpy, slower", name, exc_info=True)
        return None

    return wrap
