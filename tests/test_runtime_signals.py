"""The stop request that replaces rclpy's signal handler: one signal asks for an orderly stop, a second one
falls through to the default action, and the previous handlers come back afterwards."""
import os
import signal
import threading
import time

import pytest

from flagbot_sim.ros.runtime import StopRequest


def _deliver(sig):
    os.kill(os.getpid(), sig)
    time.sleep(0.01)        # the Python-level handler runs at the next bytecode boundary of the main thread


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_first_signal_requests_a_stop_second_takes_the_default_action(sig):
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    stop = StopRequest()
    stop.install()
    try:
        assert not stop.is_set()
        _deliver(sig)
        assert stop.is_set() and stop.wait(0.0)
        # the second one is no longer ours: SIGINT raises KeyboardInterrupt, SIGTERM would terminate
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
        if sig == signal.SIGINT:
            with pytest.raises(KeyboardInterrupt):
                _deliver(sig)
    finally:
        stop.uninstall()
    assert {s: signal.getsignal(s) for s in before} == before


def test_wait_returns_when_another_thread_sets_it_and_times_out_otherwise():
    stop = StopRequest()
    t0 = time.monotonic()
    assert not stop.wait(0.25)
    assert time.monotonic() - t0 >= 0.25
    threading.Timer(0.05, stop.set).start()
    t0 = time.monotonic()
    assert stop.wait(5.0)
    assert time.monotonic() - t0 < 1.0
