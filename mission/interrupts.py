"""Ctrl-C / SIGTERM / SIGHUP while a run is ending: noted, not raised.

The first Ctrl-C (or SIGTERM or SIGHUP, which `capm-field run` turns into the same KeyboardInterrupt) stops the
mission. The ending after it (flame off, body stopped, the run log closed, summary.json written) takes
a few seconds, each step bounded by its driver timeout; a second press used to raise inside it and cut
the summary (and any step after the one it landed in). While a `HeldSignals` is started, the two
signals are recorded and the operator is told the run is already stopping. Ctrl-\\ (SIGQUIT) still
kills the process at once; the igniter board then shuts itself on the missing keep-alives.
"""

from __future__ import annotations

import os
import signal
import threading

STOP_SIGNALS = (signal.SIGTERM, signal.SIGHUP)  # what `capm-field run` turns into a Ctrl-C (its default: killed, no finally)
_HELD = (signal.SIGINT, *STOP_SIGNALS)
STOPPING = ("capm-field run: already stopping (flame off, body stopped, run log and summary being written); "
            "Ctrl-\\ kills at once\n")


class HeldSignals:
    """SIGINT / SIGTERM / SIGHUP recorded in `received` (signal names, in order) instead of raising, between
    `start()` and `stop()`. Both are idempotent; outside the main thread (where Python cannot set
    handlers) nothing is held and `start()` returns False."""

    def __init__(self, message: str = STOPPING) -> None:
        self.message = message
        self.received: list[str] = []
        self._previous: dict[int, object] | None = None
        self._raise_next = False

    def _note(self, signum: int, frame) -> None:
        name = signal.Signals(signum).name
        if self._raise_next:  # (handlers run one at a time, in the main thread: no race on the flag)
            self._raise_next = False
            raise KeyboardInterrupt(name)
        self.received.append(name)
        try:
            os.write(2, self.message.encode())  # async-signal-safe, unlike print
        except OSError:
            pass

    def start(self, raise_first: bool = False) -> bool:
        """Hold the signals from now on; with `raise_first`, the first one still raises
        KeyboardInterrupt(its name) and only the later ones are held. A run uses that for its whole
        mission: two signals arriving together (Ctrl-C and a supervisor's SIGTERM, an SSH drop's
        SIGHUP and SIGTERM) are handled back to back, and the second raised inside the `except`
        that was about to hold it, skipping the ending (no flame-off step, no summary). Called again
        without `raise_first`, every later signal is held."""
        self._raise_next = raise_first
        if self._previous is not None:
            return True
        if threading.current_thread() is not threading.main_thread():
            return False
        # a signal the process was started ignoring (SIGHUP under nohup, SIGINT in a script's background
        # job) stays ignored
        self._previous = {s: signal.signal(s, self._note) for s in _HELD if signal.getsignal(s) is not signal.SIG_IGN}
        return True

    def stop(self) -> None:
        if self._previous is None:
            return
        for s, h in self._previous.items():
            # None: a handler set outside Python; the default is the nearest we can restore
            signal.signal(s, h if h is not None else signal.SIG_DFL)
        self._previous = None
