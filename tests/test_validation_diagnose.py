"""Diagnosis on data with a hidden effect: the right effect first, the fit down to the noise floor, no false
positives; the fitted model file works in the model and the plant."""

from __future__ import annotations

import math

import numpy as np
import pytest

from franka_vs_gym.model.config import ModelConfig
from franka_vs_gym.model.franka_model import FrankaModel
from franka_vs_gym.validation.compare import compare
from franka_vs_gym.validation.diagnose import diagnose
from franka_vs_gym.validation.fitting import fit_effects
from franka_vs_gym.validation.hidden import EFFECTS, make_hidden_effect_log
from franka_vs_gym.validation.selection import n_eff
from franka_vs_gym.validation.signals import clean

DURATION = 12.0


def _check_params(effect: str, params: dict, answer: dict, fit_cfg: ModelConfig) -> None:
    """Fitted parameters against the hidden truth (independent of the RMSE criterion)."""
    a = answer["params"]
    p = params[effect]
    if effect == "payload":
        assert p["mass_kg"] == pytest.approx(a["mass_kg"], rel=0.1)
        np.testing.assert_allclose(p["com_flange_m"], a["com_flange_m"], atol=0.015)
    elif effect == "gravity_tilt":
        g = fit_cfg.gravity
        tilt = math.degrees(math.acos(-g[2] / np.linalg.norm(g)))
        assert tilt == pytest.approx(a["tilt_deg"], rel=0.1)
    elif effect == "delay":
        assert p["delay_s"] == pytest.approx(a["delay_s"], rel=0.1)
    elif effect == "torque_offset":
        j = p["joints"]
        np.testing.assert_allclose(np.array(p["offset_Nm"])[j], np.array(a["offset_Nm"])[j], atol=0.05)
        assert len(j) >= 6
    elif effect == "armature":
        j = p["joints"]
        np.testing.assert_allclose(np.array(p["armature_kgm2"])[j], np.array(a["armature_kgm2"])[j],
                                   rtol=0.2, atol=0.02)
    elif effect == "viscous_friction":
        j = p["joints"]
        np.testing.assert_allclose(np.array(p["viscous_Nms_per_rad"])[j], np.array(a["viscous_Nms_per_rad"])[j],
                                   rtol=0.25, atol=0.03)
    elif effect == "coulomb_friction":
        j = p["joints"]
        np.testing.assert_allclose(np.array(p["coulomb_Nm"])[j], np.array(a["coulomb_Nm"])[j], rtol=0.1, atol=0.02)
        assert p["coulomb_vel_rad_per_s"] == pytest.approx(a["coulomb_vel_rad_per_s"])


@pytest.mark.parametrize("magnitude,seed", [(1.0, 11), (2.0, 12)])
@pytest.mark.parametrize("effect", EFFECTS)
def test_hidden_effect_is_named_first_and_fit_reaches_noise_floor(effect, magnitude, seed):
    log, answer = make_hidden_effect_log(effect, seed, duration=DURATION, magnitude=magnitude)
    data = clean(log)
    d = diagnose(data, select=False)
    assert d.verdict == effect, [(c.effect, round(c.score, 1), c.significant) for c in d.ranking[:3]]
    assert d.ranking[0].effect == effect
    f = fit_effects(data, [effect])
    assert np.all(f.rmse_after <= 1.2 * f.noise_floor), (f.rmse_after / f.noise_floor).round(3)
    assert f.rmse_after.sum() < f.rmse_before.sum()
    _check_params(effect, f.params, answer, f.after)


@pytest.mark.parametrize("seed", [21, 22, 23])
def test_no_hidden_effect_gives_verdict_none(seed):
    log, _ = make_hidden_effect_log("none", seed, duration=DURATION)
    d = diagnose(log)
    assert d.verdict == "none", [(c.effect, round(c.score, 1)) for c in d.ranking[:3]]
    assert not any(c.significant for c in d.ranking)
    assert d.selected == [] and d.explained, d.unexplained.text
    # the default model is right: its residual is the measurement noise
    np.testing.assert_allclose(d.rmse_tau, d.noise_floor, rtol=0.05)


def test_noise_floor_matches_injected_noise():
    log, answer = make_hidden_effect_log("none", 3, duration=DURATION)
    data = clean(log)
    np.testing.assert_allclose(data.noise, answer["torque_noise_Nm"], rtol=0.08)


def test_effective_sample_size():
    rng = np.random.default_rng(0)
    n = 20000
    assert n_eff(rng.normal(size=n)) == pytest.approx(n, rel=0.1)
    rho = 0.9
    e = rng.normal(size=n)
    x = np.empty(n)
    x[0] = e[0]
    for k in range(1, n):
        x[k] = rho * x[k - 1] + e[k]
    assert n_eff(x) == pytest.approx(n * (1 - rho) / (1 + rho), rel=0.2)


def test_fitted_model_file_loads_and_the_plant_uses_it(tmp_path):
    log, answer = make_hidden_effect_log("payload", 31, duration=8.0, magnitude=1.5)
    data = clean(log)
    f = fit_effects(data, ["payload"])
    path = f.after.save(tmp_path / "calibrated.json")
    with pytest.raises(FileExistsError):
        f.after.save(path)
    cfg = ModelConfig.load(path)
    assert cfg.payload is not None and cfg.payload.mass == pytest.approx(answer["params"]["mass_kg"], rel=0.1)
    # the model: gravity torque of the calibrated model differs from the default by the payload's weight
    q = data.q[100]
    dg = FrankaModel(path).gravity(q) - FrankaModel().gravity(q)
    assert np.abs(dg).max() > 0.5
    # the plant: replaying the logged controller in the plant built from the calibrated file reproduces the measured
    # torques much better than the default plant
    before = compare(data, None, do_replay=True)
    after = compare(data, str(path), do_replay=True)
    assert before.replay.mode == "controller"
    assert after.replay.rmse_tau.sum() < 0.5 * before.replay.rmse_tau.sum()
    assert np.all(after.replay.rmse_tau <= 1.5 * data.noise)
    assert np.all(after.rmse_tau <= 1.2 * data.noise)


def test_link_inertials_base_parameters_and_model_file(tmp_path):
    """The link-inertial effect: 43 base parameters for the FER's kinematics (QR of the joint-torque regressor;
    the rank of an independent SVD agrees), its fit explains a hidden link-inertial error to the noise floor, and
    re-identified link inertials survive the model file and reach the plant."""
    from dataclasses import replace

    from franka_vs_gym.model.description import FER
    from franka_vs_gym.model.params import LinkInertial
    from franka_vs_gym.sim.robot import FrankaSim
    from franka_vs_gym.validation.effects import Context, get_effect

    e = get_effect("link_inertials")
    b = e.basis(ModelConfig())
    sv = np.linalg.svd(b["W"], compute_uv=False)
    assert len(b["cols"]) == int(np.sum(sv > 1e-8 * sv[0])) == 43
    log, answer = make_hidden_effect_log("link_inertials", 7, duration=8.0)
    data = clean(log)
    ctx = Context(data, ModelConfig())
    f = e.fit(ctx, ctx.residual, np.arange(ctx.n))
    after = np.sqrt(np.mean((ctx.residual - e.contribution(ctx, f)) ** 2, axis=0))
    assert np.all(after <= 1.05 * data.noise) and np.any(np.sqrt(np.mean(ctx.residual ** 2, 0)) > 1.3 * data.noise)
    # persistence: a re-identified arm is written to and read from the model file, and the plant gets it
    links = list(FER.links)
    links[3] = LinkInertial(links[3].mass * 1.2, links[3].com, tuple(np.array(links[3].inertia) * 1.2))
    cfg = ModelConfig().copy(robot=replace(FER, links=tuple(links)))
    path = cfg.save(tmp_path / "arm.json")
    loaded = ModelConfig.load(path)
    assert loaded.robot.links[3].mass == pytest.approx(1.2 * FER.links[3].mass)
    assert "links" not in ModelConfig().to_dict()
    q = FER.neutral()
    assert np.abs(FrankaModel(path).gravity(q) - FrankaModel().gravity(q)).max() > 0.3
    sim = FrankaSim(model=path, camera=False, table=False)
    masses = sim.world.model.body_mass.tolist()
    assert any(m == pytest.approx(1.2 * FER.links[3].mass) for m in masses)
