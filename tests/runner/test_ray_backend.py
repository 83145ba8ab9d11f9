"""The Ray backend's signal handling around ``ray.init`` (no Ray started: its handler is imitated)."""

import signal
import sys

import pytest

from silfit.cli.interrupts import Interrupted, interrupts_raise
from silfit.runner.ray_backend import _signal_handlers_kept


def _ray_like_handler():
    """What ``ray.init`` installs in the driver: SIGTERM exits with status 15."""
    signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(signum))


def test_the_command_lines_handlers_come_back_after_ray_init():
    with interrupts_raise():
        cli = signal.getsignal(signal.SIGTERM)
        with _signal_handlers_kept():
            _ray_like_handler()
        assert signal.getsignal(signal.SIGTERM) is cli and signal.getsignal(signal.SIGINT) is cli
        with pytest.raises(ValueError):  # ray.init failing (a bad address): back as well
            with _signal_handlers_kept():
                _ray_like_handler()
                raise ValueError("no cluster there")
        assert signal.getsignal(signal.SIGTERM) is cli


def test_a_sigterm_while_ray_starts_is_the_command_lines_interrupt():
    """Ray's handler exits with status 15 (``SystemExit``) while it starts: that becomes the command line's
    interrupt (exit status 143, its one line), with both signals set aside for the cleanup."""
    with interrupts_raise():
        with pytest.raises(Interrupted) as caught:
            with _signal_handlers_kept():
                _ray_like_handler()
                signal.raise_signal(signal.SIGTERM)
        assert caught.value.exit_code == 143
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN and signal.getsignal(signal.SIGINT) is signal.SIG_IGN


def test_an_interrupts_cleanup_keeps_the_signals_aside_and_a_library_run_keeps_rays_handler():
    with interrupts_raise():
        with pytest.raises(Interrupted):
            with _signal_handlers_kept():
                _ray_like_handler()
                signal.raise_signal(signal.SIGINT)  # the command line's handler: both signals aside
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
    previous = signal.signal(signal.SIGTERM, signal.SIG_DFL)  # a library caller: the default, not a function
    try:
        with _signal_handlers_kept():
            _ray_like_handler()
        assert callable(signal.getsignal(signal.SIGTERM))  # Ray's, as Ray left it
        with pytest.raises(SystemExit):
            with _signal_handlers_kept():
                raise SystemExit(15)
    finally:
        signal.signal(signal.SIGTERM, previous)
