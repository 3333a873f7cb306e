"""A signal inside ``runtime.interrupts.deferred`` waits for the block's end (an evaluated walk's
files are written whole), under the command's own handlers."""

import os
import signal

import pytest

from mapfilter.cli import Terminated, _sigterm_as_interrupt
from mapfilter.runtime.interrupts import clear, deferred, deferring


def test_a_signal_in_a_deferred_block_is_raised_when_the_block_ends():
    steps = []
    clear()
    with _sigterm_as_interrupt(), pytest.raises(Terminated):
        with deferred():
            os.kill(os.getpid(), signal.SIGTERM)  # the handler runs at the next bytecode: here
            steps.append("after the signal")
            with deferred():  # an inner block's end does not raise it: the outer one is still open
                pass
            steps.append("the block's end")
        steps.append("after the block")
    assert steps == ["after the signal", "the block's end"] and not deferring()


def test_without_a_deferred_block_the_signal_cuts_at_once_and_a_block_error_comes_first():
    steps = []
    clear()
    with _sigterm_as_interrupt(), pytest.raises(Terminated):
        os.kill(os.getpid(), signal.SIGTERM)
        steps.append("after the signal")
    assert steps == []
    clear()
    with _sigterm_as_interrupt(), pytest.raises(OSError, match="disk full"):
        with deferred():
            os.kill(os.getpid(), signal.SIGTERM)
            raise OSError("disk full")  # the block's own error is raised, not the signal
    clear()
    assert not deferring()
