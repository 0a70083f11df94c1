"""``--mcap FILE``: the run read back with the ``mcap`` reader and checked against the log itself, the command's
JSON and an independent gravity-torque computation (pinocchio through FrankaModel)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from franka_vs_gym.cli import main as cli
from franka_vs_gym.validation.hidden import make_hidden_effect_log
from franka_vs_gym.validation.logs import save_log

mcap_reader = pytest.importorskip("mcap.reader", reason="the mcap package is not installed (pip install mcap)")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("mcap")
    log, answer = make_hidden_effect_log("gravity_tilt", 41, duration=8.0, magnitude=1.5)
    p = save_log(log, tmp / "tilt.csv")
    out = tmp / "run.mcap"
    return p, out, log, answer


def _read(path: Path) -> tuple[dict, dict, list]:
    """topic -> (times ns, messages), topic -> schema, metadata."""
    by_topic: dict[str, tuple[list, list]] = {}
    schemas = {}
    with open(path, "rb") as fh:
        reader = mcap_reader.make_reader(fh)
        for schema, channel, msg in reader.iter_messages():
            assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
            schemas[channel.topic] = json.loads(schema.data)
            t, m = by_topic.setdefault(channel.topic, ([], []))
            t.append(msg.log_time)
            m.append(json.loads(msg.data))
        meta = list(reader.iter_metadata())
    return by_topic, schemas, meta


def _arr(msgs: list, key: str) -> np.ndarray:
    return np.array([[np.nan if v is None else v for v in m[key]] for m in msgs], float)


def test_mcap_holds_measurement_model_residual_effects_findings(run, capsys):
    p, out, log, answer = run
    assert cli(["diagnose", str(p), "--mcap", str(out), "--json", "--quiet"]) == 0
    d = json.loads(capsys.readouterr().out)
    topics, schemas, meta = _read(out)
    assert {"/measured", "/model", "/residual", "/effects/gravity_tilt", "/findings"} <= set(topics)
    for topic in ("/measured", "/model", "/residual"):
        for key in schemas[topic]["required"]:
            assert key in topics[topic][1][0]
    # the measurement is the log's own: tau_J at each message time equals the CSV row at that time
    t_ns, msgs = topics["/measured"]
    t = np.array(t_ns) * 1e-9
    assert np.all(np.diff(t) > 0)
    rows = np.searchsorted(log.time - log.time[0], t - 1e-7)
    np.testing.assert_allclose(_arr(msgs, "tau_J"), log.tau_J[rows], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(_arr(msgs, "q"), log.q[rows], atol=2e-3)  # filtered q: within the filter's smoothing
    # model and residual on the same timeline: residual = measured - model, its RMS is the JSON's per-joint RMSE
    model = _arr(topics["/model"][1], "tau_before")
    res = _arr(topics["/residual"][1], "before")
    # (each value written with 6 significant digits: 1e-4 Nm on torques of tens of Nm, three values in the sum)
    np.testing.assert_allclose(res, _arr(msgs, "tau_J") - model, atol=3e-4)
    np.testing.assert_allclose(np.sqrt(np.mean(res ** 2, axis=0)), d["rmse_tau"], rtol=0.05)
    np.testing.assert_allclose(_arr(topics["/residual"][1], "noise_floor")[0], d["noise_floor"], atol=1e-4)
    # the effect's torque is the gravity torque of the fitted gravity change, computed independently
    from franka_vs_gym.model.franka_model import FrankaModel
    from franka_vs_gym.validation.compare import baseline_config

    sel = next(s for s in d["selected"] if s["effect"] == "gravity_tilt")
    cfg = baseline_config(log)
    m0 = FrankaModel(cfg)
    m1 = FrankaModel(cfg.copy(gravity=np.asarray(cfg.gravity) + np.array(sel["params"]["delta_gravity_m_per_s2"])))
    te, em = topics["/effects/gravity_tilt"]
    tau_eff = _arr(em, "tau")
    te = np.array(te) * 1e-9
    q_at = np.stack([np.interp(te, t, _arr(msgs, "q")[:, j]) for j in range(7)], 1)
    k = np.linspace(0, len(te) - 1, 60).astype(int)
    expect = np.array([m1.gravity(q_at[i]) - m0.gravity(q_at[i]) for i in k])
    scale = np.abs(expect).max()
    assert scale > 0.5  # a 6 degree tilt moves Nm of gravity torque
    np.testing.assert_allclose(tau_eff[k], expect, atol=0.02 * scale)
    # the findings: the command's verdict and selection, once at the start
    f = topics["/findings"][1]
    assert len(f) == 1 and f[0]["verdict"] == d["verdict"] == "gravity_tilt"
    assert topics["/findings"][0][0] == t_ns[0]
    assert meta and meta[0].name == "franka_vs" and meta[0].metadata["verdict"] == "gravity_tilt"


def test_mcap_refuses_to_overwrite_and_to_replace_the_log(run, capsys):
    p, out, _, _ = run
    if not out.exists():
        out.write_bytes(b"not ours")
    before = out.read_bytes()
    assert cli(["compare", str(p), "--mcap", str(out), "--quiet", "--no-replay"]) == 2
    assert "exists" in capsys.readouterr().err and out.read_bytes() == before
    assert cli(["compare", str(p), "--mcap", str(p), "--force", "--quiet", "--no-replay"]) == 2
    assert "input" in capsys.readouterr().err
