"""The one error type silfit raises for bad input files and values.

:class:`InputError` is a :class:`ValueError` (so existing ``except ValueError`` code keeps
working) whose message is one line starting with the file (or argument) it concerns,
naming the field where there is one. The command line prints it and exits with status 2.
"""
from __future__ import annotations

import os
from typing import Optional, Union

__all__ = ["InputError", "UnsafeFileError"]

# Every bad input silfit reports is an InputError: files and fields (here), command-line
# options (silfit.cli.CLIError is this class), dataset inputs (silfit.runner), subject
# folders (silfit.dataset.SubjectError) and photos with nobody in them
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


class UnsafeFileError(InputError):
    """A file asked to run code or build an object silfit does not allow (a pickle
    naming a class outside the allow-list of :mod:`silfit.safe_pickle`)."""
