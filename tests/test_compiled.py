"""`capm_field.compiled.kernel`: a loop numba cannot compile, or no numba at all, leaves None and a
warning (the caller then runs its numpy formulation), never an exception at import."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from capm_field import axis_votes, compiled, vegetation


def test_compiles_a_loop() -> None:
    @compiled.kernel(lambda nb: nb.float64(nb.float64[:]))
    def total(a):
        s = 0.0
        for v in a:
            s += v
        return s

    assert total is not None and total(np.array([1.0, 2.0, 3.5])) == 6.5


def test_a_loop_that_does_not_compile_is_none_with_a_warning(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, logger="capm_field.compiled")

    @compiled.kernel(lambda nb: nb.float64(nb.float64[:]))
    def broken(a):
        return {"not": object()}[a]  # nothing numba can type

    assert broken is None
    assert "could not compile" in caplog.text and "broken" in caplog.text


def test_without_numba_every_loop_is_none_with_a_warning(monkeypatch, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, logger="capm_field.compiled")
    monkeypatch.setattr(compiled, "numba", None)
    monkeypatch.setattr(compiled, "_missing", ImportError("No module named 'numba'"))

    @compiled.kernel(lambda nb: nb.float64(nb.float64[:]))
    def total(a):
        return a.sum()

    assert total is None
    assert "numba is not available" in caplog.text and "No module named" in caplog.text


def test_a_loop_that_cannot_be_cached_is_still_compiled() -> None:
    # numba caches beside the source file; code without one (here: exec'd) has no cache directory
    ns = {"kernel": compiled.kernel}
    exec(
        "@kernel(lambda nb: nb.int64(nb.int64))\n"
        "def twice(n):\n"
        "    return 2 * n\n",
        ns,
    )
    assert ns["twice"] is not None and ns["twice"](21) == 42


def test_the_detectors_loops_are_compiled_here() -> None:
    # numba is a dependency: a missing or failing compile would only show as a slower detector
    assert vegetation._gstar_u8 is not None
    assert axis_votes._line_votes_loop is not None
