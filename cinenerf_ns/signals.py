"""SIGTERM and SIGHUP handled like SIGINT by the command-line tools (cinesplat-plan, cinesplat-preview).

Python turns SIGINT into KeyboardInterrupt, so every ``with`` block unwinds and removes what it staged (output_set's
hidden folder, atomic writes' temporary files, ffmpeg). SIGTERM and SIGHUP kill the process at once by default and
leave those behind. Inside ``signals_as_interrupts()`` they raise ``Terminated`` (a KeyboardInterrupt), the same
clean-up runs, and ``interrupted(e)`` gives the exit status (128 + the signal: 143, 129; 130 for SIGINT) and the word
for the one line the tool prints. Further signals are ignored while the first one unwinds (a second SIGTERM during
clean-up would leave it half done).
"""
from __future__ import annotations

import contextlib
import signal
from typing import Iterator, Tuple

HANDLED = (signal.SIGTERM, signal.SIGHUP)


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP arrived (raised by the handler signals_as_interrupts installs)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = int(signum)


def _raise(signum, frame) -> None:
    for s in (*HANDLED, signal.SIGINT):  # the first signal wins: clean-up is not interrupted again
        signal.signal(s, signal.SIG_IGN)
    raise Terminated(signum)


@contextlib.contextmanager
def signals_as_interrupts() -> Iterator[None]:
    """SIGTERM and SIGHUP raise Terminated in the main thread while the block runs; the previous handlers (and
    SIGINT's) come back at its end."""
    old = {}
    try:
        for s in (*HANDLED, signal.SIGINT):
            old[s] = signal.getsignal(s)
        for s in HANDLED:
            signal.signal(s, _raise)
    except ValueError:  # not the main thread: signals stay as they are
        old = {}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)


def interrupted(e: KeyboardInterrupt) -> Tuple[int, str]:
    """(exit status, what happened) of an interrupt: (143, 'terminated (SIGTERM)'), (129, 'hung up (SIGHUP)') or
    (130, 'interrupted')."""
    if isinstance(e, Terminated):
        name = signal.Signals(e.signum).name
        return 128 + e.signum, ("hung up" if e.signum == signal.SIGHUP else "terminated") + f" ({name})"
    return 130, "interrupted"
