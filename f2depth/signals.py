"""SIGTERM ends a run as Ctrl-C does: ``kill``, a scheduler's stop or ``docker stop`` raise
:class:`Terminated` (a KeyboardInterrupt) in the main thread, so every ``finally`` and atomic writer
(f2depth.io) cleans up on the way out. The stages (f2depth.stage) and the CLI (f2depth.cli) run inside
:func:`sigterm_as_interrupt` and exit 143 with one line.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, a scheduler's stop, ``docker stop``) raised in the main thread like Ctrl-C, so
    that every ``finally`` and atomic writer cleans up as it does for Ctrl-C."""


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """While inside, SIGTERM raises :class:`Terminated` (a KeyboardInterrupt); the previous handler is put
    back afterwards. Outside the main thread (where Python cannot set handlers) nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: object) -> None:
        raise Terminated(signum)

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
