"""Stopping ``franka-vs serve``: the sockets close only after the serving thread has ended."""

from __future__ import annotations

from conftest import loopback_host

from franka_vs_gym.fci import FCIServer

NET = 213  # this file's loopback net (conftest.loopback_host)


def test_stop_waits_for_the_serving_thread_even_when_its_join_was_interrupted():
    """On Python < 3.13 a ``Thread.join`` interrupted by a signal's exception (SIGTERM or Ctrl-C while
    ``serve_forever`` waits) can leave the serving thread marked stopped while it still runs. ``stop`` then closed
    the sockets under it, and every ``franka-vs serve --record`` stopped by SIGTERM after a franky client ended in
    a traceback ("FCI server thread failed: [Errno 9] Bad file descriptor"). Here the thread object answers as such
    an interrupted join leaves it: the thread must still end cleanly, with no error."""
    srv = FCIServer(loopback_host(NET), lockstep=True, camera=False, verbose=False)
    srv.start()
    real = srv._thread

    class MarkedStopped:  # what an interrupted join can leave: not alive, join returns at once
        def is_alive(self) -> bool:
            return False

        def join(self, timeout: float | None = None) -> None:
            return None

    srv._thread = MarkedStopped()
    srv.stop()
    real.join(5.0)
    assert not real.is_alive()
    assert srv._error is None, srv._error
