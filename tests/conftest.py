import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
CLIENTS = Path(__file__).parent / "fci_clients"  # scripts of the real FCI clients (pylibfranka, franky)


def run_in_both_plants(code: str) -> dict[str, str]:
    """stdout of ``python -c code`` with the compiled plant (key "0") and with the pure-Python fallback forced
    (key "1", ``FRANKA_VS_GYM_PURE_PYTHON=1``), each in its own process."""
    import subprocess
    import sys

    out = {}
    for flag in ("0", "1"):
        env = dict(os.environ, FRANKA_VS_GYM_PURE_PYTHON=flag)
        out[flag] = subprocess.run([sys.executable, "-W", "ignore", "-c", code], env=env, capture_output=True,
                                   text=True, check=True).stdout
    return out


def loopback_host(net: int) -> str:
    """A loopback address of its own for this test process (the FCI ports are fixed): 127.<net>.x.y from the pid,
    so parallel workers and parallel test runs on one machine do not collide (each test file uses its own nets)."""
    pid = os.getpid()
    return f"127.{net}.{(pid // 250) % 250 + 1}.{pid % 250 + 1}"


def record_with_client(script: str, out: Path, net: int) -> dict:
    """Run the client ``CLIENTS/script HOST OUT`` in its own process against a lock-step FCI server on
    :func:`loopback_host` ``(net)``; returns the JSON summary the script prints last."""
    import json
    import subprocess
    import sys

    from franka_vs_gym.fci import FCIServer

    with FCIServer(loopback_host(net), lockstep=True, camera=False, verbose=False) as srv:
        r = subprocess.run([sys.executable, str(CLIENTS / script), srv.host, str(out)], capture_output=True,
                           text=True, timeout=180)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def record_served(script: Path, args: list[str], log: Path, net: int, timeout: float = 300, **server):
    """Run the client ``script HOST *args`` unmodified in its own process against a lock-step FCI server on
    :func:`loopback_host` ``(net)`` that records to ``log`` (``server``: more FCIServer arguments, e.g. ``truth``,
    ``tool``); returns the server, stopped, for what the caller checks of its plant."""
    import subprocess
    import sys

    from franka_vs_gym.fci import FCIServer

    with FCIServer(loopback_host(net), lockstep=True, camera=False, verbose=False, record=log, **server) as srv:
        r = subprocess.run([sys.executable, str(script), srv.host, *args], capture_output=True, text=True,
                           timeout=timeout)
    assert r.returncode == 0, r.stderr[-3000:]
    return srv


def log_context(path):
    """The diagnosis context (the baseline model's evaluation and regressors) of the recording at ``path``, as
    ``diagnose`` builds it."""
    from franka_vs_gym.validation.compare import as_processed, baseline_config
    from franka_vs_gym.validation.effects.base import Context
    from franka_vs_gym.validation.signals import decimated

    data = as_processed(str(path))
    return Context(decimated(data), baseline_config(data.log, None, False, data=data))


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def random_q(rng, n=1, margin=0.05):
    from franka_vs_gym.model import params

    lo, hi = params.as_array(params.Q_MIN) + margin, params.as_array(params.Q_MAX) - margin
    return rng.uniform(lo, hi, size=(n, 7))
