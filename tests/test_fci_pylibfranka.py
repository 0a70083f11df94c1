"""franka-vs serve with pylibfranka (Franka's own Python bindings) as the client, lock-step mode.

Each client script in tests/fci_clients runs unmodified in its own process (as against the real robot) and prints
JSON; the server runs in this process. The model, the simulator and libfranka's own model (from the URDF the server
hands out) are independent computations compared here.
"""

from __future__ import annotations

import importlib.util
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

# the clients run in their own processes (pylibfranka and franky cannot share one): only check it is installed
if importlib.util.find_spec("pylibfranka") is None:
    pytest.skip("pylibfranka is not installed (pip install -e '.[fci]')", allow_module_level=True)

from franka_vs_gym.fci import FCIServer, codec  # noqa: E402
from franka_vs_gym.model import FrankaModel  # noqa: E402

CLIENTS = Path(__file__).parent / "fci_clients"
ROOT = Path(__file__).resolve().parents[1]


def _host() -> str:
    """A loopback address of its own per xdist worker (the FCI ports are fixed)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    return f"127.0.21.{1 + int(worker[2:] or 0)}"


def run_client(script: str | Path, *args: str, timeout: float = 60) -> dict:
    r = subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.fixture
def server():
    with FCIServer(_host(), lockstep=True, camera=False, verbose=False) as srv:
        yield srv


def test_read_state_and_model(server):
    out = run_client(CLIENTS / "read_state.py", server.host)
    q = np.array(out["q"])
    sim_q = server.sim.get_position()
    assert np.allclose(q, sim_q, atol=1e-6)  # float32 on the wire
    assert out["robot_mode"].endswith("Idle") and not out["errors"]
    assert out["later_time"] > out["time"]  # states keep flowing while idle
    model = FrankaModel()
    # libfranka's model (built from our URDF + the hand in the state's load fields) vs FrankaModel with the hand
    B = np.array(out["mass"]).reshape(7, 7, order="F")
    assert np.abs(B - model.mass_matrix(q)).max() < 1e-6
    assert np.abs(np.array(out["gravity"]) - model.gravity(q)).max() < 1e-4
    assert abs(out["m_total"] - 0.73) < 1e-6
    # conventions: O_T_EE is the flange pose times F_T_EE (hand TCP), column-major; tau_J includes gravity
    O_T_EE = np.array(out["O_T_EE"]).reshape(4, 4, order="F")
    assert np.abs(O_T_EE - model.fMe(q)).max() < 1e-5
    assert np.abs(np.array(out["tau_J"]) - model.gravity(q)).max() < 1e-3
    assert np.allclose(out["O_ddP_O"], [0, 0, -9.81])
    assert out["elbow"][0] == pytest.approx(q[2], abs=1e-6) and out["elbow"][1] == -1.0


def test_incompatible_version_gets_an_answer(server):
    with socket.create_connection((server.host, codec.ROBOT_PORT), timeout=5) as s:
        s.sendall(codec.robot_message(codec.Command.CONNECT, 1, codec.CONNECT_REQUEST.pack(9, 40000)))
        data = s.recv(64)
    command, cid, size = codec.ROBOT_HEADER.unpack_from(data)
    status, version = codec.CONNECT_RESPONSE.unpack_from(data, codec.ROBOT_HEADER.size)
    assert (command, cid, size) == (codec.Command.CONNECT, 1, len(data))
    assert status == codec.ConnectStatus.INCOMPATIBLE_LIBRARY_VERSION and version == 10


def test_gravity_free_torque_control_holds_still(server):
    out = run_client(CLIENTS / "torque_hold.py", server.host, "1000")
    q = np.array(out["q"])
    assert len(q) == 1000
    assert np.abs(q - q[0]).max() < 1e-6  # zero torque: the robot compensates its own gravity
    # tau_J measured = libfranka model's gravity at rest
    assert np.abs(np.array(out["tau_J"]) - np.array(out["gravity"])).max() < 1e-3
    assert np.allclose(np.diff(out["time"]), 0.001)  # one state per command, 1 ms apart


def test_internal_joint_impedance_tracks_joint_position_motion(server):
    out = run_client(CLIENTS / "joint_impedance_internal.py", server.host)
    q0, q = np.array(out["q0"]), np.array(out["q"])
    assert q[2] - q0[2] == pytest.approx(0.3, abs=1e-3) and q[3] - q0[3] == pytest.approx(0.3, abs=1e-3)
    assert out["max_tracking_error"] < 1e-3
    assert out["mode"].endswith("Idle")


def test_joint_impedance_example_reaches_target_bit_identically(server):
    a = run_client(ROOT / "examples" / "fci_joint_impedance.py", server.host, "--json")
    assert a["error"] < 1e-3
    with FCIServer(server.host.replace(".21.", ".22."), lockstep=True, camera=False, verbose=False) as other:
        b = run_client(ROOT / "examples" / "fci_joint_impedance.py", other.host, "--json")
    assert a["log"] == b["log"]  # lock-step: two identical runs, identical trajectories bit for bit


@pytest.mark.parametrize("kind, reason", [
    ("torque_jump", "controller_torque_discontinuity"),
    ("position_limit", "joint_position_limits_violation"),
    ("velocity", "joint_motion_generator_velocity_limits_violation"),
])
def test_reflex_reason_and_recovery(server, kind, reason):
    out = run_client(CLIENTS / "reflex.py", server.host, kind)
    assert out["raised"] is not None and "motion aborted by reflex" in out["raised"]
    assert f'"{reason}"' in out["raised"]
    assert out["mode_after"].endswith("Reflex")
    assert reason in out["last_motion_errors"] and reason in out["current_errors"]
    assert out["mode_recovered"].endswith("Idle") and not out["errors_recovered"]
    if kind == "position_limit":
        assert out["q_at_reflex"][6] > 2.8973 - 1e-3
        assert out["q_end"][6] < out["q_at_reflex"][6] - 0.02  # moving back out of the limit is allowed
