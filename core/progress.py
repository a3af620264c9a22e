"""Progress reporting and cancellation shared by long-running stages.

A stage takes ``progress: Progress | None``; it calls ``progress.update(done, total,
message)`` and ``progress.check()`` (raises :class:`Cancelled` when the caller asked
to stop).  The command line prints to stderr; the Blender add-on feeds a progress bar
and sets the cancel flag on Esc.
"""

from __future__ import annotations

import sys
import threading
import time


class Cancelled(Exception):
    """The user cancelled a long-running stage."""


class Progress:
    """Progress sink with a cancel flag.

    Parameters
    ----------
    callback : callable, optional
        ``callback(fraction, message)``; default prints a line on stderr at most
        every ``interval`` seconds.
    """

    def __init__(self, callback=None, interval: float = 1.0, stream=None):
        self._callback = callback
        self._interval = interval
        self._last = 0.0
        self._stream = stream if stream is not None else sys.stderr
        self.cancel_event = threading.Event()

    def update(self, done: float, total: float, message: str = "") -> None:
        frac = 0.0 if total <= 0 else min(1.0, max(0.0, done / total))
        if self._callback is not None:
            self._callback(frac, message)
        else:
            now = time.monotonic()
            if now - self._last >= self._interval or frac >= 1.0:
                self._last = now
                print(f"[{100 * frac:5.1f}%] {message}", file=self._stream, flush=True)
        self.check()

    def cancel(self) -> None:
        self.cancel_event.set()

    def check(self) -> None:
        if self.cancel_event.is_set():
            raise Cancelled("cancelled by the user")


def null_progress() -> Progress:
    """A progress sink that prints nothing (still honours cancel)."""
    return Progress(callback=lambda frac, msg: None)


def prefixed(progress: Progress | None, text: str) -> Progress | None:
    """A sink that forwards to ``progress`` with ``text`` before every message and
    shares its cancel flag (None stays None): a stage run twice says which run it is."""
    if progress is None:
        return None
    out = Progress(callback=lambda frac, msg: progress.update(frac, 1.0, text + msg))
    out.cancel_event = progress.cancel_event
    return out
