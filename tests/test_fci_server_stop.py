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


def test_ctrl_c_stops_serve_started_with_sigint_ignored():
    """A process inherits an ignored SIGINT from its parent (a shell script's ``franka-vs serve &``, a test runner's
    worker), and Python then installs no Ctrl-C handler: ``kill -INT`` was lost and the server served on (seen as a
    hang of the serve command-line test under pytest-xdist, whose workers ignore SIGINT). The command installs the
    handler itself, so the signal stops it and it exits 0."""
    import selectors
    import signal
    import subprocess
    import sys

    host = loopback_host(NET + 1)
    p = subprocess.Popen([sys.executable, "-m", "franka_vs_gym.cli", "serve", "--host", host, "--lockstep",
                          "--no-camera"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        with selectors.DefaultSelector() as sel:  # a guard against a hang, not a timing: minutes on a loaded machine
            sel.register(p.stdout, selectors.EVENT_READ)
            assert sel.select(timeout=300), "the server printed no ready line"
        assert "ready at " + host in p.stdout.readline()
        p.send_signal(signal.SIGINT)
        assert p.wait(timeout=120) == 0, p.stderr.read()
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
