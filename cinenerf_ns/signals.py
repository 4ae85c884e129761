"""SIGTERM and SIGHUP handled like SIGINT by the command-line tools (cinesplat-plan, cinesplat-preview).

Python turns SIGINT into KeyboardInterrupt, so every ``with`` block unwinds and removes what it staged (output_set's
hidden folder, atomic writes' temporary files, ffmpeg). SIGTERM and SIGHUP kill the process at once by default and
leave those behind. Inside ``signals_as_interrupts()`` all three raise ``Terminated`` (a KeyboardInterrupt), the same
clean-up runs, and ``interrupted(e)`` gives the exit status (128 + the signal: 143, 129, 130) and the word for the one
line the tool prints.

Two traps of raising from a signal handler are closed here. A handler runs wherever the main thread is, also inside
a weakref callback or a ``__del__`` run by the garbage collector, where Python swallows the exception ("Exception
ignored in ...") and carries on: ``sys.unraisablehook`` sees that, says nothing, and raises it again at the next line
the interrupted code runs (a trace function on its frames). And further signals are ignored while the first one
unwinds (a second SIGTERM during clean-up would leave it half done).
"""
from __future__ import annotations

import contextlib
import signal
import sys
from typing import Iterator, Tuple

HANDLED = (signal.SIGTERM, signal.SIGHUP, signal.SIGINT)


class Terminated(KeyboardInterrupt):
    """SIGTERM, SIGHUP or SIGINT arrived (raised by the handler signals_as_interrupts installs)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = int(signum)


_unwinding = False  # a Terminated is on its way up: later signals are ignored


def _raise(signum, frame) -> None:
    global _unwinding
    if _unwinding:
        return
    _unwinding = True
    raise Terminated(signum)


def _raise_on_next_line(signum: int) -> None:
    """Raise Terminated at the next line the interrupted code runs (the frames below the caller), through a trace
    function: an exception a trace function raises propagates in the traced frame."""
    frames = []
    f = sys._getframe(2)  # the frame the swallowed handler interrupted
    while f is not None:
        frames.append((f, f.f_trace))
        f = f.f_back
    tracer = sys.gettrace()  # a coverage tool's, say: given back

    def local(frame, event, arg):
        sys.settrace(tracer)
        for fr, old in frames:
            fr.f_trace = old
        raise Terminated(signum)

    for fr, _ in frames:
        fr.f_trace = local
    sys.settrace(tracer or (lambda *a: None))  # tracing on: the frames above get their line events


def _unraisable(hook):
    def swallowed(u) -> None:
        if isinstance(u.exc_value, Terminated):  # raised where Python ignores exceptions: raise it again, later
            _raise_on_next_line(u.exc_value.signum)
            return
        hook(u)
    return swallowed


@contextlib.contextmanager
def signals_as_interrupts() -> Iterator[None]:
    """SIGTERM, SIGHUP and SIGINT raise Terminated in the main thread while the block runs; the previous handlers come
    back at its end."""
    global _unwinding
    old = {}
    try:
        for s in HANDLED:
            old[s] = signal.signal(s, _raise)
    except ValueError:  # not the main thread: signals stay as they are
        for s, h in old.items():
            signal.signal(s, h)
        old = {}
    hook, _unwinding = sys.unraisablehook, False
    sys.unraisablehook = _unraisable(hook)
    try:
        yield
    finally:
        sys.unraisablehook = hook
        for s, h in old.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)
        _unwinding = False


def interrupted(e: KeyboardInterrupt) -> Tuple[int, str]:
    """(exit status, what happened) of an interrupt: (143, 'terminated (SIGTERM)'), (129, 'hung up (SIGHUP)') or
    (130, 'interrupted')."""
    if isinstance(e, Terminated) and e.signum != signal.SIGINT:
        name = signal.Signals(e.signum).name
        return 128 + e.signum, ("hung up" if e.signum == signal.SIGHUP else "terminated") + f" ({name})"
    return 130, "interrupted"
