"""The robot as a value: one friction law, one inertia helper, model files that name their robot, no reach-ins."""

import json
import math
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
    stribeck_friction,
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
    st, vs = rng.uniform(0.1, 1.0, 7), rng.uniform(0.02, 0.3, 7)
    fast_st = compile_friction(p1, p2, p3, visc, coul, cv, st, vs)
    qfrc_st = np.zeros(7)
    hook_st = make_plant_friction(qvel, qfrc_st, p1, p2, p3, visc, coul, cv, scale=0.7, stribeck=st, stribeck_vel=vs)
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
        # the Stribeck term (Armstrong-Helouvry et al. 1994's exponential curve, its sign smoothed like Coulomb's),
        # element by element with math functions, also near the Stribeck velocities
        for x in (dq, dq * 0.05):
            hump = np.array([st[j] * math.exp(-(x[j] / vs[j]) ** 2) * math.tanh(x[j] / cv) for j in range(7)])
            np.testing.assert_allclose(stribeck_friction(x, st, vs, cv), hump, rtol=0, atol=1e-12)
            full_st = _published_sigmoid(x, p1, p2, p3) + visc * x + coul * np.tanh(x / cv) + hump
            np.testing.assert_allclose(joint_friction(x, p1, p2, p3, visc, coul, cv, st, vs), full_st, rtol=0,
                                       atol=1e-12)
            np.testing.assert_allclose(fast_st(x), full_st, rtol=0, atol=1e-12)
            qvel[:] = x
            hook_st()
            np.testing.assert_allclose(qfrc_st, -0.7 * full_st, rtol=0, atol=1e-12)
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


# ---------------------------------------------------------------- every registered robot: model, plant, limits
# Joint origins (xyz m, rpy rad) of franka_description's kinematics.yaml, the same for the FER and the FR3: an
# independent route to the kinematics (URDF roll-pitch-yaw parsed by pinocchio, not the modified-DH rows).
_HALF_PI = 1.570796326794897
URDF_JOINTS = [((0, 0, 0.333), (0, 0, 0)), ((0, 0, 0), (-_HALF_PI, 0, 0)), ((0, -0.316, 0), (_HALF_PI, 0, 0)),
               ((0.0825, 0, 0), (_HALF_PI, 0, 0)), ((-0.0825, 0.384, 0), (-_HALF_PI, 0, 0)),
               ((0, 0, 0), (_HALF_PI, 0, 0)), ((0.088, 0, 0), (_HALF_PI, 0, 0))]
URDF_FLANGE_Z = 0.107


def _independent_urdf(desc) -> str:
    out = ['<robot name="x"><link name="link0"/>']
    for i, ((xyz, rpy), link) in enumerate(zip(URDF_JOINTS, desc.links, strict=True)):
        ixx, ixy, ixz, iyy, iyz, izz = link.inertia
        out.append(f'<link name="link{i + 1}"><inertial><origin xyz="{" ".join(map(repr, link.com))}"/>'
                   f'<mass value="{link.mass!r}"/><inertia ixx="{ixx!r}" ixy="{ixy!r}" ixz="{ixz!r}" iyy="{iyy!r}" '
                   f'iyz="{iyz!r}" izz="{izz!r}"/></inertial></link>')
        out.append(f'<joint name="j{i + 1}" type="revolute"><origin xyz="{" ".join(map(str, xyz))}" '
                   f'rpy="{" ".join(map(str, rpy))}"/><parent link="link{i}"/><child link="link{i + 1}"/>'
                   '<axis xyz="0 0 1"/><limit effort="100" velocity="10" lower="-7" upper="7"/></joint>')
    out.append(f'<link name="link8"/><joint name="flange" type="fixed"><origin xyz="0 0 {URDF_FLANGE_Z}"/>'
               '<parent link="link7"/><child link="link8"/></joint></robot>')
    return "".join(out)


def _random_q(desc, rng, n, margin=0.05):
    lim = desc.limit_arrays()
    return rng.uniform(lim["q_min"] + margin, lim["q_max"] - margin, (n, 7))


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_model_matches_an_independent_urdf_model(name, rng):
    """B(q), C dq + g and the flange pose of FrankaModel(robot=..., tool=None) equal those of a pinocchio model
    parsed from a URDF written with the published joint origins and link inertials."""
    import pinocchio as pin

    desc = robot_description(name)
    ref = pin.buildModelFromXML(_independent_urdf(desc))
    data = ref.createData()
    fl = ref.getFrameId("link8")
    model = FrankaModel(robot=name, tool=None)
    assert model.config.friction.is_zero() == (desc.friction is None)
    for q in _random_q(desc, rng, 20):
        dq = rng.uniform(-2, 2, 7)
        B = np.triu(pin.crba(ref, data, q))
        np.testing.assert_allclose(model.mass_matrix(q), B + np.triu(B, 1).T, atol=1e-10)
        np.testing.assert_allclose(model.bias(q, dq), pin.nonLinearEffects(ref, data, q, dq), atol=1e-9)
        pin.framesForwardKinematics(ref, data, q)
        np.testing.assert_allclose(model.fMfl(q), data.oMf[fl].homogeneous, atol=1e-12)


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_model_matches_the_plant(name, rng):
    """The MuJoCo plant built from the description agrees with the model library (hand, payload, armature)."""
    import mujoco

    from franka_vs_gym.assets.mjcf import RobotSpec, SceneSpec, scene_xml
    from franka_vs_gym.model import RigidBody

    cfg = ModelConfig(robot=name, payload=RigidBody(0.8, [0.01, 0.0, 0.06], [1e-3, 2e-3, 1e-3]),
                      armature=np.full(7, 0.1))
    fm = FrankaModel(cfg)
    m = mujoco.MjModel.from_xml_string(scene_xml(SceneSpec(robots=[RobotSpec(config=cfg, camera=False)],
                                                           table=False)))
    d = mujoco.MjData(m)
    M = np.zeros((7, 7))
    for q in _random_q(cfg.robot, rng, 20):
        d.qpos[:] = q
        d.qvel[:] = rng.uniform(-2, 2, 7)
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, d, M)
        np.testing.assert_allclose(fm.mass_matrix(q), M, atol=1e-6)
        np.testing.assert_allclose(fm.bias(q, d.qvel), d.qfrc_bias, atol=1e-6)
    lim = cfg.robot.limits
    np.testing.assert_allclose(m.jnt_range, np.c_[lim.q_min, lim.q_max])
    np.testing.assert_allclose(m.actuator_ctrlrange[7:], np.c_[-np.array(lim.dq_max), lim.dq_max])


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_simulator_respects_the_robots_limits(name):
    from franka_vs_gym.sim import FORCE_TORQUE, JOINT_STATE, VELOCITY, FrankaSim

    desc = robot_description(name)
    lim = desc.limit_arrays()
    sim = FrankaSim(robot=name, camera=False)
    assert sim.model.robot is desc
    np.testing.assert_allclose(sim.get_position(), desc.q_neutral)
    bad = desc.neutral()
    bad[5] = lim["q_min"][5] - 0.1  # below joint 6's lower limit
    with pytest.raises(ValueError, match="outside the joint limits"):
        sim.reset(bad)
    # a joint velocity command far beyond the limits is scaled down to them (direction kept)
    sim.set_robot_state(VELOCITY)
    cmd = np.zeros(7)
    cmd[4] = 10.0
    sim.set_velocity(JOINT_STATE, cmd)
    sim.wait(0.3)
    assert abs(sim.get_velocity()[4]) == pytest.approx(lim["dq_max"][4], rel=0.03)
    # torque commands beyond the limits are saturated: the joint torque (command + gravity) stays within tau_max
    sim.reset(desc.q_neutral)
    sim.reflexes = False  # one step at full torque spins a light wrist past its velocity limit (a reflex)
    sim.set_robot_state(FORCE_TORQUE)
    sim.set_force_torque(JOINT_STATE, np.full(7, 500.0))
    sim.step()
    tau = sim.get_force_torque()
    assert (np.abs(tau) <= lim["tau_max"] + 1e-9).all()
    assert tau[0] == pytest.approx(lim["tau_max"][0])


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_every_environment_takes_the_robot(name):
    import gymnasium as gym

    from franka_vs_gym.envs.registration import ENVS

    lim = robot_description(name).limit_arrays()
    for env_id in sorted(ENVS):
        env = gym.make(env_id, robot=name)
        u = env.unwrapped
        assert u.config.robot.name == name
        _, info = env.reset(seed=1)
        q = u.robot.get_position()
        assert (q >= lim["q_min"]).all() and (q <= lim["q_max"]).all()
        hi = lim["tau_max"] if u.action_type == "torque" else lim["dq_max"]
        if u.action_type in ("torque", "joint_velocity"):
            # the robot's limits bound the physical actions (the default space is normalized, its scale within them)
            np.testing.assert_allclose(u.physical_action_bounds, hi)
            assert (u.action_scale <= hi).all()
            phys = gym.make(env_id, robot=name, action_scale="physical")
            np.testing.assert_allclose(phys.action_space.high, hi.astype(np.float32))
            phys.close()
        env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        env.close()


def test_fr3_numbers_are_the_published_ones():
    """Spot checks against franka_description robots/fr3 (joint_limits.yaml, inertials.yaml) and the FCI limits."""
    from franka_vs_gym.model.description import FR3

    assert FR3.limits.q_min[5] == 0.5445 and FR3.limits.q_max[5] == 4.5169
    assert FR3.limits.dq_max == (2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26)
    assert FR3.links[0].mass == 2.9274653454 and FR3.links[6].com == (0.0045225817, 0.0086261921, -0.0161633251)
    assert FR3.limits.ddq_max == (10.0,) * 7 and FR3.cartesian_limits.v_max == 3.0
    assert FR3.friction is None and FR3.joint_names[0] == "fr3_joint1"
    for link in FR3.links:  # physically consistent: positive definite, triangle inequality on principal moments
        w = np.linalg.eigvalsh(link.inertia_matrix())
        assert w.min() > 0 and w[0] + w[1] >= w[2]


def test_no_module_outside_sim_touches_franka_sim_private_attributes():
    """Environments, the workbench, the FCI server... use FrankaSim's public methods (set_dynamics, set_tool,
    joint_views...), never its underscore attributes."""
    from franka_vs_gym.sim import FrankaSim

    sim = FrankaSim(camera=False)
    private = sorted(k for k in vars(sim) if k.startswith("_")) + sorted(
        k for k in vars(FrankaSim) if k.startswith("_") and not k.startswith("__"))
    pat = re.compile(r"\b(?!self\b)[A-Za-z_]\w*\.(" + "|".join(map(re.escape, private)) + r")\b")
    roots = [PACKAGE, PACKAGE.parent / "baselines", PACKAGE.parent / "scripts", PACKAGE.parent / "examples"]
    bad = []
    for root in roots:
        for p in sorted(root.rglob("*.py")):
            rel = p.relative_to(PACKAGE.parent).as_posix()
            if rel.startswith("franka_vs_gym/sim/"):
                continue
            bad += [f"{rel}: {m.group(0)}" for m in pat.finditer(p.read_text())]
    assert not bad, bad


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_scripted_policies_servo_and_track_on_every_robot(name):
    import franka_vs_gym
    from franka_vs_gym.policies import ComputedTorquePolicy, IBVSPolicy

    lim = robot_description(name).limit_arrays()
    ibvs = IBVSPolicy(robot=name)
    np.testing.assert_array_equal(ibvs.dq_max, lim["dq_max"])
    r = franka_vs_gym.evaluate(ibvs, "FrankaIBVS-v0", 2, seed=0, env_kwargs={"robot": name})
    assert r["success_rate"] == 1.0, r["failures"]
    ct = ComputedTorquePolicy(robot=name)
    np.testing.assert_array_equal(ct.tau_max, lim["tau_max"])
    r = franka_vs_gym.evaluate(ct, "FrankaTorqueTracking-v0", 1, seed=0, env_kwargs={"robot": name, "time_limit": 2.0})
    assert r["success_rate"] == 1.0, r["failures"]


def test_command_line_takes_the_robot(tmp_path, capsys):
    from franka_vs_gym.cli import main

    out = tmp_path / "eval.json"
    assert main(["evaluate", "zero", "--robot", "fr3", "--episodes", "1", "--quiet", "--json", str(out),
                 "--env-kwargs", '{"time_limit": 0.2}']) == 0
    assert json.loads(out.read_text())["env_kwargs"]["robot"] == "fr3"
    assert main(["evaluate", "zero", "--robot", "ur5", "--episodes", "1"]) == 2
    assert main(["demo", "torque", "--robot", "ur5", "--out", str(tmp_path / "d")]) == 2
    assert "unknown robot 'ur5'" in capsys.readouterr().err


def test_identified_link_inertials_survive_the_model_file(tmp_path):
    """A configuration whose robot carries identified link inertials (the workbench's link_inertials effect) keeps
    them through save/load: the file stores them next to the robot's name; other changes must be registered."""
    from dataclasses import replace

    from franka_vs_gym.model.params import LinkInertial

    links = list(FER.links)
    links[6] = LinkInertial(1.1, (0.01, 0.0, 0.05), (0.01, 0.0, 0.0, 0.01, 0.0, 0.005))
    cfg = ModelConfig().copy(robot=replace(FER, links=tuple(links)))
    back = ModelConfig.load(cfg.save(tmp_path / "m.json"))
    assert back.robot == cfg.robot and back.robot.links[6].mass == 1.1
    q = FER.neutral()
    np.testing.assert_allclose(FrankaModel(back).gravity(q), FrankaModel(cfg).gravity(q), atol=1e-12)
    assert "links" not in ModelConfig().to_dict()  # the registered robot is named only
    other = ModelConfig().copy(robot=replace(FER, q_neutral=(0.0, -0.5, 0.0, -2.0, 0.0, 1.5, 0.7)))
    with pytest.raises(ValueError, match="register it under its own name"):
        other.save(tmp_path / "other.json")
    d = cfg.to_dict()
    d["links"] = d["links"][:3]
    with pytest.raises(ValueError, match="list of 7"):
        ModelConfig.from_dict(d)


@pytest.mark.parametrize("tool", ["franka_hand", "none"])
@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_velocity_servo_steps_settle_without_overshoot_on_every_joint(name, tool):
    """A step of 98 % of the velocity limit on one joint (the largest FrankaSim passes on) is reached within
    0.1 s (the torque limit bounds the acceleration of the heavy proximal joints) without overshoot or limit cycle,
    with and without the hand: the servo gains suit each robot's inertias (a gain tuned for the FER's wrist puts
    the FR3's lighter link 7 into a 0 <-> 6.4 rad/s cycle)."""
    from franka_vs_gym.model import ModelConfig
    from franka_vs_gym.sim import JOINT_STATE, VELOCITY, FrankaSim

    for j in range(7):
        sim = FrankaSim(ModelConfig(robot=name, tool=None if tool == "none" else tool), camera=False, table=False,
                        reflexes=False)
        v_cmd = 0.98 * sim.dq_max[j]
        sim.set_robot_state(VELOCITY)
        v = np.zeros(7)
        v[j] = v_cmd
        trace = []
        for _ in range(150):
            sim.set_velocity(JOINT_STATE, v)
            sim.step()
            trace.append(sim.get_velocity()[j])
        trace = np.array(trace) / v_cmd
        assert trace.max() < 1.02, f"{name}/{tool} joint {j}: overshoot to {trace.max():.3f} of the command"
        assert np.all(np.abs(trace[100:] - 1.0) < 0.02), f"{name}/{tool} joint {j}: not settled: {trace[100:]}"
