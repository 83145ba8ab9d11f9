"""The one error type silfit raises for bad input files and values.

:class:`InputError` is a :class:`ValueError` (so existing ``except ValueError`` code keeps
working) whose message is one line starting with the file (or argument) it concerns,
naming the field where there is one. The command line prints it and exits with status 2.
"""

from __future__ import annotations

import os
import re
from typing import Optional, Union

__all__ = [
    "InputError",
    "UnsafeFileError",
    "SystemLibraryError",
    "interruption",
    "interrupt_cleanup",
    "quoted",
    "cut_quotes",
    "QUOTE_CHARS",
]

#: Most characters of a value read from a file that an error message quotes.
QUOTE_CHARS = 24

# Every bad input silfit reports is an InputError: files and fields (here), command-line
# options (silfit.cli.CLIError is this class), dataset inputs (silfit.runner), subject
# folders (silfit.io.subjects.SubjectError) and photos with nobody in them
# (silfit.detect.DetectionError) are subclasses or the class itself.


class InputError(ValueError):
    """A bad input: ``"<source>: <message>"`` on one line; ``source`` is the file (or the
    argument) and ``field`` the field inside it, where there is one."""

    def __init__(self, source: Union[str, os.PathLike], message: Optional[str] = None, field: Optional[str] = None):
        if message is None:  # one ready line ("<source>: <message>"), as command-line checks raise it
            source, _, message = str(source).partition(": ") if ": " in str(source) else ("", "", str(source))
        self.source = os.fspath(source) if isinstance(source, (str, os.PathLike)) else str(source)
        self.field = field
        text = " ".join(str(message).split())  # one line, whatever the message held
        super().__init__(f"{self.source}: {text}" if self.source else text)


class SystemLibraryError(RuntimeError):
    """A system library silfit needs is missing (libLLVM for Mitsuba/Dr.Jit, libOSMesa for the
    offscreen pictures): the message is one line saying what to install. The command line prints
    it and exits with status 2."""


class UnsafeFileError(InputError):
    """A file asked to run code or build an object silfit does not allow (a pickle
    naming a class outside the allow-list of :mod:`silfit.io.safe_pickle`)."""


def quoted(value, limit: int = QUOTE_CHARS) -> str:
    """A value read from a file, as an error message may quote it: at most ``limit``
    characters of its text, escaped (``ascii``: no control characters, no non-ASCII), with
    the length of what was left out. Messages end up in logs and ``failures.jsonl``, and a
    file may hold anything (a manifest may name any file on the machine)."""
    if isinstance(value, (bytes, bytearray, str)):
        head = ascii(value[:limit])
        return head if len(value) <= limit else f"{head[:-1]}...{head[-1]} ({len(value)} characters)"
    text = ascii(value)
    return text if len(text) <= limit else f"{text[:limit]}..."


_QUOTE = re.compile(r"'((?:[^'\\]|\\.)*)'")  # a string as repr() writes it, as library messages quote values


def cut_quotes(message: str, limit: int = QUOTE_CHARS) -> str:
    """A library's message (numpy's "could not convert string to float: '...'") with every
    quoted string cut to ``limit`` characters, as :func:`quoted` cuts silfit's own quotes."""

    def cut(m):
        body = m.group(1)
        return m.group(0) if len(body) <= limit else f"'{body[:limit]}...' ({len(body)} characters)"

    return _QUOTE.sub(cut, message)


def interruption(err: BaseException) -> Optional[KeyboardInterrupt]:
    """The interrupt (``KeyboardInterrupt``: Ctrl-C, or the command line's SIGTERM) that ``err`` is or
    was raised while handling, if any: a signal inside ``np.savez`` leaves a zip member open, and
    closing the archive on the way out raises ``ValueError``, which is the interrupt, not bad input."""
    seen, todo = set(), [err]
    while todo:  # both links: ``raise X from Y`` while handling an interrupt keeps it in the context
        e = todo.pop(0)
        if e is None or id(e) in seen:
            continue
        if isinstance(e, KeyboardInterrupt):
            return e
        seen.add(id(e))
        todo += [e.__cause__, e.__context__]
    return None


def interrupt_cleanup(err: BaseException) -> bool:
    """Whether ``err`` is an interrupt whose handler set SIGINT and SIGTERM aside for the cleanup on the way
    out (:mod:`silfit.cli.interrupts`): a block that replaced a signal's handler leaves it aside then, rather
    than putting its own back."""
    import signal

    return isinstance(err, KeyboardInterrupt) and signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
