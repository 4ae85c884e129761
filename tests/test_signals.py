"""signals.py: SIGTERM / SIGHUP / SIGINT raise Terminated inside signals_as_interrupts (also when the handler runs
inside a __del__ or weakref callback, where Python would swallow it), later signals are ignored while it unwinds,
and the previous handlers come back."""
import gc
import os
import signal

import pytest

from cinenerf_ns.signals import Terminated, interrupted, signals_as_interrupts


@pytest.mark.parametrize("sig,code,word", [(signal.SIGTERM, 143, "terminated (SIGTERM)"),
                                           (signal.SIGHUP, 129, "hung up (SIGHUP)"),
                                           (signal.SIGINT, 130, "interrupted")])
def test_signal_raises_terminated_and_handlers_come_back(sig, code, word):
    before = signal.getsignal(sig)
    with pytest.raises(Terminated) as e:
        with signals_as_interrupts():
            os.kill(os.getpid(), sig)
            for _ in range(1000):  # the handler runs at the next bytecode boundary
                pass
            pytest.fail("no Terminated")
    assert interrupted(e.value) == (code, word) and isinstance(e.value, KeyboardInterrupt)
    assert signal.getsignal(sig) is before
    assert interrupted(KeyboardInterrupt()) == (130, "interrupted")


class _KillsInDel:
    def __del__(self):
        os.kill(os.getpid(), signal.SIGTERM)  # the handler runs here, where an exception is only printed


def test_a_signal_handled_inside_del_is_raised_again_in_the_interrupted_code(capsys):
    reached = []
    with pytest.raises(Terminated):
        with signals_as_interrupts():
            x = _KillsInDel()
            del x
            gc.collect()
            for i in range(100):
                reached.append(i)
            pytest.fail("the swallowed Terminated was not raised again")
    assert len(reached) < 100
    assert "Exception ignored" not in capsys.readouterr().err


def test_later_signals_are_ignored_while_the_first_unwinds():
    cleaned = []
    with pytest.raises(Terminated):
        with signals_as_interrupts():
            try:
                os.kill(os.getpid(), signal.SIGTERM)
                for _ in range(1000):
                    pass
            finally:
                os.kill(os.getpid(), signal.SIGHUP)  # a second signal during clean-up
                for _ in range(1000):
                    pass
                cleaned.append(True)
    assert cleaned == [True]
