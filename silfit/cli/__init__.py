"""The ``silfit`` command line: one entry point, one module per subcommand.

Each subcommand lives in ``silfit/cli/<name>.py`` and exposes
``register(subparsers)``, which adds its parser and sets ``func`` (a callable taking
the parsed ``argparse.Namespace`` and returning an exit code).
"""

from __future__ import annotations

import argparse
import errno
import importlib
import importlib.util
import os
import sys

from ..errors import InputError

#: Subcommands in the order ``silfit --help`` lists them.
SUBCOMMANDS = ("demo", "fit", "detect", "synth", "eval", "render", "fit-dataset", "export-model", "report")


#: A bad command line: the one input-error type (one clear line, no traceback, exit code 2).
CLIError = InputError


def warn(text: str) -> None:
    """A warning about a fit or an input, on standard error (``--quiet`` hides progress only)."""
    print(f"warning: {text}", file=sys.stderr)


def note(text: str) -> None:
    """A note on a choice silfit made for the user (a model, a camera), on standard error."""
    print(text, file=sys.stderr)


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = argparse.ArgumentParser(
        prog="silfit", description="Recover SMPL pose, shape and camera from 2D keypoints and a person silhouette."
    )
    parser.add_argument("--version", action="version", version=f"silfit {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS:
        module = f"{__name__}.{name.replace('-', '_')}"  # fit-dataset -> fit_dataset.py
        if importlib.util.find_spec(module) is None:
            continue
        importlib.import_module(module).register(sub)
    from .flags import finish_parser

    for name, subparser in sub.choices.items():
        finish_parser(name, subparser)  # examples in every --help, no docstring markup
    return parser


#: Errors only writing raises: with no file named, they concern the output folder.
_WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS}


def _describe(err: Exception, args) -> str:
    """The error's line: an error of the system as ``<path>: <reason>`` (a full disk names
    the output folder, the only place silfit writes)."""
    if isinstance(err, OSError) and err.strerror:
        path = err.filename
        if path is None and err.errno in _WRITE_ERRNOS and getattr(args, "out", None):
            return f"{args.out}: {err.strerror} (writing the output)"
        if path is not None:
            return f"{os.fspath(path)}: {err.strerror}"
    return str(err)


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)  # no subcommand: a usage error, as argparse treats one
        return 2
    from .interrupts import interrupts_raise

    with interrupts_raise():
        return run_command(args)


def run_command(args) -> int:
    """``args.func(args)``'s exit code, with bad input, memory and interrupts as one line each. An
    error raised while an interrupt unwinds (a zip file closed with a member half written) is the
    interrupt: it is reported as such and exits with its code."""
    from ..errors import interruption
    from .interrupts import Interrupted

    try:
        return int(args.func(args) or 0)
    except BaseException as err:
        stop = interruption(err)
        if stop is not None:  # the handler's Interrupted (128 + its signal), or a plain Ctrl-C (130)
            print(f"silfit {args.command}: interrupted ({str(stop) or 'SIGINT'})", file=sys.stderr)
            return stop.exit_code if isinstance(stop, Interrupted) else 130
        if isinstance(err, (OSError, ValueError)):  # bad input: silfit.errors.InputError (CLIError) is a ValueError
            print(f"silfit {args.command}: error: {' '.join(_describe(err, args).split())}", file=sys.stderr)
            return 2
        from ..errors import SystemLibraryError

        if isinstance(err, SystemLibraryError):  # libLLVM or libOSMesa missing: what to install, one line
            print(f"silfit {args.command}: error: {' '.join(str(err).split())}", file=sys.stderr)
            return 2
        if isinstance(err, MemoryError):
            print(
                f"silfit {args.command}: error: out of memory (is an input far larger than intended?)", file=sys.stderr
            )
            return 2
        raise


if __name__ == "__main__":
    sys.exit(main())
