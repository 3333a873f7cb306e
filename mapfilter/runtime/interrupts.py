"""Ctrl-C and SIGTERM that are never lost.

Python raises a signal's exception in the main thread at the next bytecode, wherever that is;
raised inside a weakref callback or a ``__del__`` the collector ran, it is only printed
("Exception ignored in ...") and the run goes on: an interrupted ``evaluate`` once finished with
exit code 0. The command's handlers (``mapfilter.cli``) note each signal here, and long work
calls :func:`raise_pending_signal` between its tasks (``cli.common.ProgressBar``), which raises
it again if it was lost. A few milliseconds of work that must end whole (an evaluated walk's
files) run in :func:`deferred`: a signal there is noted and raised as the block ends.
"""

from __future__ import annotations

import contextlib
import signal

__all__ = ["Terminated", "clear", "deferred", "deferring", "interrupted_by", "note_signal", "raise_pending_signal"]

_PENDING: list[int] = []  # the signals since the last raise_pending_signal
_DEFERRING: list[int] = [0]  # how many deferred blocks are open


class Terminated(KeyboardInterrupt):
    """Raised in the main thread on SIGTERM, so that a terminated run cleans up as Ctrl-C does."""


def note_signal(signum: int) -> None:
    """A SIGINT or SIGTERM came (its handler raises its exception next)."""
    _PENDING.append(signum)


def clear() -> None:
    """Forget the signals noted so far (a command starts)."""
    _PENDING.clear()


def deferring() -> bool:
    """A :func:`deferred` block is open: the command's handlers note a signal and return."""
    return _DEFERRING[0] > 0


@contextlib.contextmanager
def deferred():
    """A block that a SIGINT or SIGTERM does not cut short: the signal is noted, and raised when
    the block (the outermost one) ends without an error of its own."""
    _DEFERRING[0] += 1
    try:
        yield
    finally:
        _DEFERRING[0] -= 1
    if not _DEFERRING[0]:
        raise_pending_signal()


def raise_pending_signal() -> None:
    """Raise again the SIGINT or SIGTERM noted since the last call (``KeyboardInterrupt`` or
    ``Terminated``), once."""
    if _PENDING:
        signum = _PENDING[-1]
        _PENDING.clear()
        raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def interrupted_by(exc: BaseException) -> int | None:
    """The signal (SIGINT or SIGTERM) behind an error, or None: a ``KeyboardInterrupt`` anywhere
    in its chain of causes and contexts, else the last signal noted since the command began. A
    handler that raised inside code which turned its exception into another (numba's dispatcher
    loading a kernel from its cache reports "returned a result with an exception set", the
    interrupt one or more contexts down) ends the run as the signal, not as a crash."""
    seen: set[int] = set()
    link: BaseException | None = exc
    while link is not None and id(link) not in seen:
        seen.add(id(link))
        if isinstance(link, KeyboardInterrupt):
            return signal.SIGTERM if isinstance(link, Terminated) else signal.SIGINT
        link = link.__cause__ or link.__context__
    return _PENDING[-1] if _PENDING else None
