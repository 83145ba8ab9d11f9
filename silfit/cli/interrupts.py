"""SIGINT and SIGTERM during a command: raised as :class:`Interrupted` (a
``KeyboardInterrupt``) so every ``try/except BaseException`` cleanup on the way out runs
(``silfit fit`` removes its temporary output folder), and the command exits with
``128 + signal`` after one line. Further signals are ignored while that cleanup runs."""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager

__all__ = ["Interrupted", "interrupts_raise"]

_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(KeyboardInterrupt):
    """The command was stopped by ``signum``."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


def _raise(signum, frame):
    for s in _SIGNALS:  # let the cleanup finish
        signal.signal(s, signal.SIG_IGN)
    raise Interrupted(signum)


@contextmanager
def interrupts_raise():
    """Within the block, SIGINT/SIGTERM raise :class:`Interrupted` (main thread only; the
    previous handlers come back afterwards)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, _raise) for s in _SIGNALS}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
