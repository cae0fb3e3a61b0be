"""mission.interrupts.HeldSignals: Ctrl-C / SIGTERM noted, not raised, while a run ends."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from mission.interrupts import HeldSignals


def _deliver(sig: int) -> None:
    os.kill(os.getpid(), sig)
    time.sleep(0.05)  # the handler runs in the main thread between bytecodes


@pytest.fixture
def python_sigint():
    """Python's KeyboardInterrupt handler on SIGINT (a background job starts with SIGINT ignored), and a
    SIGTERM that cannot kill pytest; both given back after the test."""
    old = signal.signal(signal.SIGINT, signal.default_int_handler), signal.signal(signal.SIGTERM, lambda *_: None)
    yield
    signal.signal(signal.SIGINT, old[0])
    signal.signal(signal.SIGTERM, old[1])


def test_held_signals_are_recorded_and_the_handlers_given_back(capfd, python_sigint):
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    h = HeldSignals("held\n")
    assert h.start() and h.start()  # idempotent
    _deliver(signal.SIGINT)
    _deliver(signal.SIGTERM)
    _deliver(signal.SIGINT)
    h.stop()
    h.stop()
    assert h.received == ["SIGINT", "SIGTERM", "SIGINT"]
    assert capfd.readouterr().err.count("held") == 3
    assert {s: signal.getsignal(s) for s in before} == before
    with pytest.raises(KeyboardInterrupt):  # Python's own handler again
        _deliver(signal.SIGINT)


def test_outside_the_main_thread_nothing_is_held(python_sigint):
    got = []
    t = threading.Thread(target=lambda: got.append(HeldSignals().start()))
    t.start()
    t.join()
    assert got == [False]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
