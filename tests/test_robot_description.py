"""The robot as a value: one friction law, one inertia helper, model files that name their robot, no reach-ins."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from franka_vs_gym.model import FrankaModel, Friction, ModelConfig
from franka_vs_gym.model.description import FER, ROBOTS, robot_description
from franka_vs_gym.model.friction import (
    compile_friction,
    gaz_sigmoid,
    joint_friction,
    make_plant_friction,
    sigmoid_tanh_coefficients,
)
from franka_vs_gym.model.geometry import combine_inertials, parallel_axis

PACKAGE = Path(__file__).resolve().parents[1] / "franka_vs_gym"


# ---------------------------------------------------------------- friction: one law, every form agrees
def _published_sigmoid(dq, p1, p2, p3):
    """Gaz et al. 2019 eq. (6), element by element with math.exp (an independent evaluation)."""
    import math
    return np.array([p1[j] / (1 + math.exp(-p2[j] * (dq[j] + p3[j]))) - p1[j] / (1 + math.exp(-p2[j] * p3[j]))
                     for j in range(7)])


def test_friction_forms_agree_to_1e12(rng):
    fr = FER.friction
    p1, p2, p3 = (np.array(x) for x in (fr.phi1, fr.phi2, fr.phi3))
    visc, coul, cv = rng.uniform(0, 0.5, 7), rng.uniform(0, 0.8, 7), 0.02
    fast_sig = compile_friction(p1, p2, p3)
    fast_all = compile_friction(p1, p2, p3, visc, coul, cv)
    qvel, qfrc = np.zeros(7), np.zeros(7)
    hook = make_plant_friction(qvel, qfrc, p1, p2, p3, visc, coul, cv, scale=0.7)
    a, b, c, e = sigmoid_tanh_coefficients(p1, p2, p3)
    for dq in rng.uniform(-2.5, 2.5, (200, 7)):
        ref = _published_sigmoid(dq, p1, p2, p3)
        np.testing.assert_allclose(gaz_sigmoid(dq, p1, p2, p3), ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast_sig(dq), ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a * np.tanh(b * dq + c) + e, ref, rtol=0, atol=1e-12)
        full = ref + visc * dq + coul * np.tanh(dq / cv)
        np.testing.assert_allclose(joint_friction(dq, p1, p2, p3, visc, coul, cv), full, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast_all(dq), full, rtol=0, atol=1e-12)
        qvel[:] = dq
        hook()
        np.testing.assert_allclose(qfrc, -0.7 * full, rtol=0, atol=1e-12)
    # vectorised over samples, and zero at rest
    dq = rng.uniform(-1, 1, (50, 7))
    np.testing.assert_allclose(Friction()(dq), np.array([_published_sigmoid(x, p1, p2, p3) for x in dq]), atol=1e-12)
    np.testing.assert_allclose(gaz_sigmoid(np.zeros(7), p1, p2, p3), 0.0, atol=1e-15)


def test_model_friction_is_the_law(rng):
    m = FrankaModel()
    fr = FER.friction
    dq = rng.uniform(-2, 2, 7)
    np.testing.assert_allclose(m.friction(dq), gaz_sigmoid(dq, np.array(fr.phi1), np.array(fr.phi2),
                                                           np.array(fr.phi3)), atol=1e-12)


# ---------------------------------------------------------------- inertia helpers
def test_combine_inertials_matches_a_point_mass_sum(rng):
    """Point masses (zero own inertia): the lumped inertia about the com is sum m_i (|r_i|^2 I - r_i r_i^T)."""
    masses = rng.uniform(0.1, 2.0, 5)
    pts = rng.uniform(-0.2, 0.2, (5, 3))
    m, c, inertia = combine_inertials((mi, p, np.zeros((3, 3))) for mi, p in zip(masses, pts, strict=True))
    assert m == pytest.approx(masses.sum())
    np.testing.assert_allclose(c, masses @ pts / masses.sum())
    ref = np.zeros((3, 3))
    for mi, p in zip(masses, pts, strict=True):
        r = p - c
        ref += mi * np.array([[r[1]**2 + r[2]**2, -r[0] * r[1], -r[0] * r[2]],
                              [-r[0] * r[1], r[0]**2 + r[2]**2, -r[1] * r[2]],
                              [-r[0] * r[2], -r[1] * r[2], r[0]**2 + r[1]**2]])
    np.testing.assert_allclose(inertia, ref, atol=1e-14)
    np.testing.assert_allclose(parallel_axis(2.0, [0, 0, 0.5]), np.diag([0.5, 0.5, 0.0]))


# ---------------------------------------------------------------- the robot in the configuration and model files
def test_default_configuration_is_the_fer():
    cfg = ModelConfig()
    assert cfg.robot is FER and cfg.tool.name == "franka_hand"
    np.testing.assert_array_equal(cfg.friction.phi1, FER.friction.phi1)
    assert FrankaModel().robot is FER
    for k, v in FER.limits.as_arrays().items():
        np.testing.assert_array_equal(FrankaModel.limits()[k], v)  # class call: the FER
        np.testing.assert_array_equal(FrankaModel().limits()[k], v)  # instance call: its robot
    assert FrankaModel(tool=None).config.tool.name == "none"
    assert ModelConfig(tool=None).tool.name == "none" and ModelConfig(friction=None).friction.is_zero()


def test_model_file_names_its_robot_and_old_files_load_as_fer(tmp_path):
    cfg = ModelConfig(armature=np.full(7, 0.1))
    p = cfg.save(tmp_path / "m.json")
    d = json.loads(p.read_text())
    assert d["robot"] == "fer" and d["format"] == "franka_vs_gym.model/2"
    assert ModelConfig.load(p).robot is FER
    # a version-1 file (written before the robot field existed) is the FER
    del d["robot"]
    d["format"] = "franka_vs_gym.model/1"
    old = tmp_path / "old.json"
    old.write_text(json.dumps(d))
    back = ModelConfig.load(old)
    assert back.robot is FER
    np.testing.assert_array_equal(back.armature, cfg.armature)
    assert FrankaModel(str(old)).robot is FER


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_model_file_for_another_robot_is_a_clear_error(tmp_path, name):
    other = next((r for r in sorted(ROBOTS) if r != name), None)
    if other is None:
        pytest.skip("one robot registered")
    p = ModelConfig(robot=name).save(tmp_path / f"{name}.json")
    assert ModelConfig.load(p, robot=name).robot.name == name
    with pytest.raises(ValueError, match=rf"describes the robot '{name}', not '{other}'"):
        ModelConfig.load(p, robot=other)
    with pytest.raises(ValueError, match=rf"describes the robot '{name}', not '{other}'"):
        FrankaModel(str(p), robot=other)
    with pytest.raises(ValueError, match="not"):
        FrankaModel(ModelConfig(robot=name), robot=other)


def test_unknown_robot_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="unknown robot 'ur5'"):
        ModelConfig(robot="ur5")
    d = ModelConfig().to_dict()
    d["robot"] = "ur5"
    with pytest.raises(ValueError, match="unknown robot 'ur5'"):
        ModelConfig.from_dict(d)
    assert robot_description("panda") is FER


# ---------------------------------------------------------------- one home: no reach-ins
def _sources(exclude: tuple[str, ...] = ()):
    for p in sorted(PACKAGE.rglob("*.py")):
        rel = p.relative_to(PACKAGE).as_posix()
        if not rel.startswith(exclude):
            yield rel, p.read_text()


def test_only_the_description_reads_the_parameter_tables():
    """Limits, DH rows, links and friction parameters are read through the robot description, never directly."""
    pat = re.compile(r"params\.(Q_MIN|Q_MAX|DQ_MAX|DDQ_MAX|DDDQ_MAX|TAU_MAX|DTAU_MAX|LINKS|FRICTION_\w+|DH_\w+|"
                     r"FLANGE_D|Q_NEUTRAL|HAND\w*|dh_placement|flange_placement|hand_\w+)\b")
    bad = [f"{rel}: {m.group(0)}" for rel, text in _sources(("model/params.py", "model/description.py"))
           for m in pat.finditer(text)]
    assert not bad, bad


def test_the_friction_law_is_written_once():
    """np.exp(-phi2 ...) appears in code only in franka_vs_gym/model/friction.py."""
    pat = re.compile(r"(np|math)\.exp\(\s*-\s*\(?\s*(phi2|p2|fr\.phi2|self\._fb)")
    bad = [rel for rel, text in _sources(("model/friction.py",)) if pat.search(text)]
    assert not bad, bad
