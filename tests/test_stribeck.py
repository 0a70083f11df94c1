"""The Stribeck term of the friction law, added end to end: a log of a plant with a hidden Stribeck hump ->
``franka-vs fit --add stribeck_friction`` -> the re-compare falls to the noise floor and the plant built from the
fitted model file replays the log; the model file stays backward compatible; asymmetric friction is writable on a
model with a sigmoid; load-dependent friction is refused with its reason."""

from __future__ import annotations

import contextlib
import importlib.util
import io
import json
import math
from pathlib import Path

import numpy as np
import pytest

from franka_vs_gym.cli import main as cli
from franka_vs_gym.model.config import Friction, ModelConfig
from franka_vs_gym.model.friction import gaz_sigmoid
from franka_vs_gym.validation.effects import Fit, NotApplicable, get_effect

ROOT = Path(__file__).resolve().parents[1]


def _json(args: list[str]) -> dict:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert cli(args) == 0
    return json.loads(buf.getvalue())


def test_fit_adds_stribeck_and_the_error_falls_in_model_and_plant(tmp_path):
    spec = importlib.util.spec_from_file_location("mhed", ROOT / "scripts" / "make_hidden_effect_data.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    log, ans_path, cal = tmp_path / "stribeck.csv", tmp_path / "answer.json", tmp_path / "cal.json"
    assert mod.main(["--effect", "stribeck_friction", "--seed", "3", "--duration", "10", "-o", str(log),
                     "--answer", str(ans_path)]) == 0
    truth = json.loads(ans_path.read_text())["params"]
    res = _json(["fit", str(log), "--add", "stribeck_friction", "-o", str(cal), "--json", "--quiet"])
    assert res["effects"] == ["stribeck_friction"] and res["holdout"]["dropped"] == []
    p = res["params"]["stribeck_friction"]
    np.testing.assert_allclose(p["F_s_Nm"], truth["F_s_Nm"], rtol=0.1, atol=0.03)
    assert p["v_s_rad_per_s"] == truth["v_s_rad_per_s"] and p["coulomb_vel_rad_per_s"] == truth[
        "coulomb_vel_rad_per_s"]
    # the model file carries the term, and the default model is well above the noise floor on this log
    fr = ModelConfig.load(cal).friction
    np.testing.assert_allclose(fr.stribeck, p["F_s_Nm"], atol=1e-6)
    before = _json(["compare", str(log), "--json", "--quiet"])
    after = _json(["compare", str(log), "--model", str(cal), "--json", "--quiet"])
    noise = np.array(after["noise_floor"])
    assert np.sum(np.square(before["rmse_tau"])) > 1.3 * np.sum(np.square(noise))
    assert np.all(np.array(after["rmse_tau"]) <= 1.02 * noise), (after["rmse_tau"], noise)
    # the plant built from the fitted file replays the logged controller: torques at the noise floor and the motion
    # 10x closer than the default plant's (the plant's friction has the term, not just the model's)
    assert before["replay"]["mode"] == after["replay"]["mode"] == "controller"
    assert np.all(np.array(after["replay"]["rmse_tau"]) <= 1.05 * noise)
    assert np.sum(after["replay"]["rmse_tau"]) < 0.9 * np.sum(before["replay"]["rmse_tau"])
    assert max(after["replay"]["rmse_q"]) < 0.1 * max(before["replay"]["rmse_q"])


def test_model_files_without_stribeck_load_unchanged_and_with_it_round_trip(tmp_path):
    cfg = ModelConfig()
    d = cfg.to_dict()
    assert "stribeck" not in d["friction"] and "stribeck_vel" not in d["friction"]  # old files' content
    old = ModelConfig.from_dict(d)
    assert not old.friction.stribeck.any()
    fr = Friction(stribeck=[0.5, 0.4, 0.3, 0.0, 0.2, 0.1, 0.05], stribeck_vel=[0.1] * 3 + [0.2] * 4,
                  coulomb_vel=0.05)
    path = ModelConfig(friction=fr).save(tmp_path / "m.json")
    back = ModelConfig.load(path).friction
    np.testing.assert_array_equal(back.stribeck, fr.stribeck)
    np.testing.assert_array_equal(back.stribeck_vel, fr.stribeck_vel)
    dq = np.linspace(-1, 1, 201)[:, None] * np.ones(7)
    np.testing.assert_array_equal(back(dq), fr(dq))
    with pytest.raises(ValueError, match="stribeck_vel"):
        Friction(stribeck=[0.1] * 7, stribeck_vel=[0.1] * 6 + [0.0])
    typo = ModelConfig().to_dict()
    typo["friction"]["stribek"] = [0.1] * 7  # a misspelt key is not silently dropped
    with pytest.raises(ValueError, match="unknown keys in friction: \\['stribek'\\]"):
        ModelConfig.from_dict(typo)
    # a Stribeck height that makes the friction push the joint is refused when a file is read
    bad = ModelConfig(friction=Friction.none()).to_dict()
    bad["friction"] |= {"coulomb": [0.1] * 7, "stribeck": [-0.5] * 7, "stribeck_vel": [0.1] * 7}
    with pytest.raises(ValueError):
        ModelConfig.from_dict(bad)


def test_asymmetric_friction_is_written_into_the_models_sigmoid():
    """On a joint with the Gaz sigmoid the fitted levels add to the sigmoid's: far from rest the new law differs
    from the old by +F_plus (dq > 0) and -F_minus (dq < 0), it is 0 at rest and it still opposes motion."""
    e = get_effect("asymmetric_friction")
    cfg = ModelConfig()
    f_plus, f_minus = np.array([0.3, -0.2, 0.1, 0.0, 0.05, 0.02, 0.01]), np.array([0.1, 0.3, -0.1, 0.2, 0.0, 0.03,
                                                                                   0.02])
    new = e.apply(cfg, Fit("asymmetric_friction", {"coef": np.column_stack([f_plus, f_minus]), "coulomb_vel": 0.02}))
    old_f, new_f = cfg.friction, new.friction
    for v, want in ((5.0, f_plus), (-5.0, -f_minus)):
        dq = np.full(7, v)
        np.testing.assert_allclose(new_f(dq) - old_f(dq), want, atol=1e-6)
    np.testing.assert_allclose(gaz_sigmoid(np.zeros(7), new_f.phi1, new_f.phi2, new_f.phi3), 0.0, atol=1e-15)
    np.testing.assert_array_equal(new_f.phi2, old_f.phi2)  # the identified widths are kept
    new.friction.check_dissipative()


def test_load_dependent_friction_is_refused_with_its_reason(tmp_path):
    e = get_effect("load_dependent_friction")
    with pytest.raises(NotApplicable) as info:
        e.apply(ModelConfig(), Fit(e.name, {"coef": np.ones((7, 1)), "coulomb_vel": 0.01}))
    msg = str(info.value)
    assert "\n" not in msg and "implicit in forward dynamics" in msg
    from franka_vs_gym.validation.fitting import fit_effects
    from franka_vs_gym.validation.hidden import make_hidden_effect_log

    log, _ = make_hidden_effect_log("none", 1, duration=3.0)
    with pytest.raises(ValueError, match="implicit in forward dynamics"):
        fit_effects(log, ["load_dependent_friction"])


def test_stribeck_law_is_armstrong_helouvry_curve_with_a_smoothed_sign():
    """Coulomb + Stribeck = tanh(dq / v_c) (F_c + (F_s - F_c) exp(-(dq / v_s)^2)): the static level F_s just after
    breakaway (dq a few v_c), the Coulomb level F_c above a few v_s, 1/e of the excess at v_s."""
    fc, fs, vs, vc = 0.4, 1.0, 0.1, 0.002
    fr = Friction(phi1=np.zeros(7), phi2=np.ones(7), phi3=np.zeros(7), coulomb=np.full(7, fc),
                  stribeck=np.full(7, fs - fc), stribeck_vel=np.full(7, vs), coulomb_vel=vc)
    assert fr(np.full(7, 5 * vc))[0] == pytest.approx(fs, rel=0.01)
    assert fr(np.full(7, -5 * vc))[0] == pytest.approx(-fs, rel=0.01)
    assert fr(np.full(7, 4 * vs))[0] == pytest.approx(fc, rel=1e-6)
    assert fr(np.full(7, vs))[0] == pytest.approx(fc + (fs - fc) / math.e, rel=1e-9)
    assert fr(np.zeros(7))[0] == 0.0
