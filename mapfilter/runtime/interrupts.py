"""Ctrl-C and SIGTERM that are never lost.

Python raises a signal's exception in the main thread at the next bytecode, wherever that is;
raised inside a weakref callback or a ``__del__`` the collector ran, it is only printed
("Exception ignored in ...") and the run goes on: an interrupted ``evaluate`` once finished with
exit code 0. The command's handlers (``mapfilter.cli``) note each signal here, and long work
calls :func:`raise_pending_signal` between its tasks (``cli.common.ProgressBar``), which raises
it again if it was lost.
"""

from __future__ import annotations

import signal

__all__ = ["Terminated", "clear", "note_signal", "raise_pending_signal"]

_PENDING: list[int] = []  # the signals since the last raise_pending_signal


class Terminated(KeyboardInterrupt):
    """Raised in the main thread on SIGTERM, so that a terminated run cleans up as Ctrl-C does."""


def note_signal(signum: int) -> None:
    """A SIGINT or SIGTERM came (its handler raises its exception next)."""
    _PENDING.append(signum)


def clear() -> None:
    """Forget the signals noted so far (a command starts)."""
    _PENDING.clear()


def raise_pending_signal() -> None:
    """Raise again the SIGINT or SIGTERM noted since the last call (``KeyboardInterrupt`` or
    ``Terminated``), once."""
    if _PENDING:
        signum = _PENDING[-1]
        _PENDING.clear()
        raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()
