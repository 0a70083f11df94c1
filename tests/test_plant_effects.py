"""The plant's joint effects the robot's model does not know (franka_vs_gym.model.joint_effects, applied inside
MuJoCo's step by franka_vs_gym/sim/_plant.c): cogging, static friction, the elastic joint and backlash. Each is
checked against its law computed here independently or against a physical property of it; the default plant is
unchanged."""

import json
import math

import numpy as np
import pytest
from conftest import loopback_host

from franka_vs_gym.errors import UserError
from franka_vs_gym.model.description import FER
from franka_vs_gym.model.joint_effects import JointEffects
from franka_vs_gym.sim import FrankaSim, plant
from franka_vs_gym.sim.robot import ControlFrame, RobotState

pytestmark = pytest.mark.skipif(not plant.NATIVE, reason="the joint effects run in the compiled plant")
NET = 237  # this file's loopback nets (conftest.loopback_host)
JS = ControlFrame.JOINT_STATE


def _torque_mode(sim, tau):
    sim.set_robot_state(RobotState.STATE_FORCE_TORQUE_CONTROL)
    sim.set_force_torque(JS, np.asarray(tau, dtype=float))


def test_default_plant_is_unchanged():
    from franka_vs_gym.assets.mjcf import RobotSpec, SceneSpec, scene_xml

    s = FrankaSim(camera=False)
    assert s._m.nuser_jnt == plant.NUSER and s._m.nuserdata == plant.RSLOT and s.joint_effects is None
    # a spec with all effects at zero writes the same scene, bit for bit
    assert scene_xml(SceneSpec()) == scene_xml(SceneSpec(robots=[RobotSpec(joint_effects=JointEffects())]))
    assert (s._m.dof_frictionloss == 0).all()


def test_cogging_is_its_law_and_integrates_to_zero_over_a_period():
    A = np.array([0.6, 0.5, 0.4, 0.3, 0.2, 0.15, 0.1])
    n = np.array([20.0, 35.0, 50.0, 64.0, 100.0, 160.0, 320.0])
    ph = np.linspace(0.1, 2.0, 7)
    s = FrankaSim(camera=False, table=False, friction=False,
                  joint_effects=JointEffects(cogging_Nm=A, cogging_cycles_per_turn=n, cogging_phase_rad=ph))
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = s.q_min + 0.2 + rng.uniform(0, 1, 7) * (s.q_max - s.q_min - 0.4)
        s.reset(q)
        tau = plant.plant_friction_torque(s._m, s._d, range(s._vs.start, s._vs.stop))
        assert np.allclose(tau, A * np.sin(n * q + ph), atol=1e-12, rtol=0)
    # over one period of its own position the ripple averages to zero and its RMS is A / sqrt(2)
    q0 = s.spec.config.robot.neutral()
    taus = []
    for k in range(64):
        s.reset(q0 + 2 * np.pi / n * k / 64)
        taus.append(plant.plant_friction_torque(s._m, s._d, range(s._vs.start, s._vs.stop)))
    taus = np.array(taus)
    assert np.abs(taus.mean(axis=0)).max() < 1e-12
    assert np.allclose(np.sqrt((taus ** 2).mean(axis=0)), A / np.sqrt(2), rtol=1e-9)


def _ramped(sim, tau, steps=600, ramp=200):
    sim.set_robot_state(RobotState.STATE_FORCE_TORQUE_CONTROL)
    q0, vmax = sim.get_position(), np.zeros(7)
    for k in range(steps):
        sim.set_force_torque(JS, np.asarray(tau) * min(1.0, (k + 1) / ramp))
        sim.step()
        vmax = np.maximum(vmax, np.abs(sim.get_velocity()))
    return sim.get_position() - q0, vmax


def test_static_friction_sticks_below_breakaway_and_slides_on_the_plants_law():
    """Loads ramped over 0.2 s on every joint at once: 0.97 of the breakaway holds (zero velocity at the end, the
    presliding deflection below 0.2 mrad), 1.05 of it breaks away; sliding, the joints feel the plant's own friction
    law (Gaz et al. 2019) and nothing of the breakaway; without static friction 0.5 of it already moves the arm."""
    F = np.array([1.0, 1.0, 0.8, 0.8, 0.4, 0.4, 0.3])
    fx = JointEffects(breakaway_Nm=F)
    s = FrankaSim(camera=False, table=False, joint_effects=fx, rotor_inertia=True)
    dq, vmax = _ramped(s, 0.97 * F)
    assert np.abs(s.get_velocity()).max() < 1e-9 and np.abs(dq).max() < 2e-4 and vmax.max() < fx.stick_vel
    s = FrankaSim(camera=False, table=False, joint_effects=fx, rotor_inertia=True)
    dq, vmax = _ramped(s, 1.05 * F)
    sliding = np.abs(s.get_velocity()) > 0.1
    assert sliding.sum() >= 5, s.get_velocity()
    tau_f = plant.plant_friction_torque(s._m, s._d, range(s._vs.start, s._vs.stop))
    assert np.allclose(tau_f[sliding], s.get_friction()[sliding], atol=1e-6), (tau_f, s.get_friction())
    s = FrankaSim(camera=False, table=False, rotor_inertia=True)
    dq, vmax = _ramped(s, 0.5 * F)
    assert vmax.max() > 0.05


def _one_elastic_joint(K=1.0e4, D=0.0, B=0.2, b=0.0, joint=0, **kw):
    z = np.zeros(7)
    Ks, Ds, Bs, bs = z.copy(), z.copy(), np.full(7, 0.1), z.copy()
    Ks[joint], Ds[joint], Bs[joint], bs[joint] = K, D, B, b
    fx = JointEffects(stiffness_Nm_per_rad=Ks, damping_Nms_per_rad=Ds, motor_inertia_kgm2=Bs, backlash_rad=bs)
    return FrankaSim(camera=False, table=False, joint_effects=fx, **kw)


def test_elastic_joint_rests_at_the_static_deflection_and_reports_the_motor_side():
    K = np.array([1.0e4, 1.0e4, 1.0e4, 1.0e4, 3.0e3, 3.0e3, 3.0e3])
    s = FrankaSim(camera=False, table=False, rotor_inertia=True,
                  joint_effects=JointEffects(stiffness_Nm_per_rad=K, damping_Nms_per_rad=[10] * 4 + [2] * 3))
    # the motors sit on the motor side: not in the joints' armature
    assert np.allclose(s._m.dof_armature[s._vs], s.spec.config.armature)
    _torque_mode(s, np.zeros(7))
    for _ in range(300):
        s.step()
    g = s.get_gravity()
    theta, dtheta = s.motor_state()
    assert np.allclose(s.get_force_torque(), g, atol=1e-6)  # tau_J: the transmission's torque
    assert np.allclose(theta - s.get_position(), g / K, atol=1e-9)
    assert np.abs(dtheta).max() < 1e-9


def test_elastic_joint_rings_at_its_natural_frequency():
    """A torque step on joint 1's motor (no damping): the deflection theta - q oscillates at
    sqrt(K (1/B + 1/M)), M the link-side inertia joint 1 feels (1 / (M^-1)_11, the other joints free)."""
    K, B, tau = 1.0e4, 0.2, 2.0
    s = _one_elastic_joint(K=K, B=B)
    q0 = s.get_position()
    Minv = np.linalg.inv(s.model.mass_matrix(q0))
    M = 1.0 / Minv[0, 0]
    _torque_mode(s, [tau, 0, 0, 0, 0, 0, 0])
    n = 400
    d = np.empty(n)
    for k in range(n):
        s.step()
        theta, _ = s.motor_state()
        d[k] = theta[0] - s.get_position()[0]
    w = math.sqrt(K * (1 / B + 1 / M))
    centred = d - tau * M / (K * (B + M))  # about the quasi-static deflection
    up = np.flatnonzero((centred[:-1] < 0) & (centred[1:] >= 0))
    t_up = (up + -centred[up] / (centred[up + 1] - centred[up])) * s.dt  # interpolated upward zero crossings
    f_seen = (len(t_up) - 1) / (t_up[-1] - t_up[0])
    assert len(t_up) >= 8
    assert f_seen == pytest.approx(w / (2 * math.pi), rel=0.02), (f_seen, w / (2 * math.pi))


def test_backlash_passes_no_torque_inside_the_gap():
    """Joint 1's motor starts in the middle of a 0.01 rad gap (no gravity on joint 1): a 1 Nm motor torque
    accelerates the motor alone until it has crossed half the gap (sqrt(2 (b/2) B / tau) = 44.7 ms); until
    then the link feels and the sensor reads no torque, afterwards the gear drives the link."""
    b, B, tau = 0.01, 0.2, 1.0
    s = _one_elastic_joint(K=1.0e4, D=5.0, B=B, b=b)
    _torque_mode(s, [tau, 0, 0, 0, 0, 0, 0])
    q0 = s.get_position()[0]
    t_contact = None
    for k in range(120):
        s.step()
        theta, _ = s.motor_state()
        inside = abs(theta[0] - s.get_position()[0]) < b / 2
        tj = s.get_force_torque()[0]
        if t_contact is None and not inside:
            t_contact = (k + 1) * s.dt
        if t_contact is None:
            assert tj == 0.0 and abs(s.get_position()[0] - q0) < 1e-15
    assert t_contact == pytest.approx(math.sqrt(2 * (b / 2) * B / tau), abs=2e-3)
    assert s.get_force_torque()[0] > 0.1 and s.get_velocity()[0] > 0


def test_cogging_of_an_elastic_joint_acts_on_its_motor():
    """On an elastic joint the ripple is the motor's: from rest (joint 1, no gravity load, no command) the first step
    accelerates the motor by -A sin(n theta + phase) / B while the link feels nothing yet (zero transmission
    torque at zero deflection)."""
    A, n, ph, B = 0.5, 40.0, 0.7, 0.2
    z = np.zeros(7)
    fx = JointEffects(stiffness_Nm_per_rad=[1e4] + [0] * 6, motor_inertia_kgm2=[B] + [0.1] * 6,
                      cogging_Nm=[A] + [0] * 6, cogging_cycles_per_turn=n, cogging_phase_rad=ph)
    s = FrankaSim(camera=False, table=False, friction=False, joint_effects=fx)
    _torque_mode(s, z)
    theta0, _ = s.motor_state()
    s.step()
    _, dtheta = s.motor_state()
    assert dtheta[0] == pytest.approx(-s.dt * A * math.sin(n * theta0[0] + ph) / B, rel=1e-9)
    assert s.get_force_torque()[0] == pytest.approx(0.0, abs=1e-12)


def test_bad_joint_effects_are_one_line_errors():
    with pytest.raises(UserError, match="too fast for a 1 ms step"):
        _one_elastic_joint(K=1.0e7, joint=6)
    with pytest.raises(UserError, match="cogging_cycles_per_turn must be > 0"):
        JointEffects(cogging_Nm=[0.5] * 7)
    with pytest.raises(UserError, match="backlash_rad must be <= 0.1"):
        JointEffects(backlash_rad=0.5)
    with pytest.raises(UserError, match="breakaway_Nm must be >= 0"):
        JointEffects(breakaway_Nm=-1)
    fx = JointEffects(backlash_rad=0.01)  # a gap alone: the gear beyond it gets the default stiffness
    assert fx.elastic.all()


def test_truth_file_joint_effects_and_the_servers_motor_side(tmp_path):
    from franka_vs_gym.fci import FCIServer
    from franka_vs_gym.fci.truth import load_truth
    from franka_vs_gym.model.config import ModelConfig

    items = [{"effect": "cogging", "A": 0.4, "k": 40, "joints": [2, 4]},
             {"effect": "elastic", "K": [2e4] * 4 + [5e3] * 3, "damping_Nms_per_rad": 5.0},
             {"effect": "backlash", "b_rad": 0.002},
             {"effect": "static_friction", "breakaway_Nm": [0.5] * 7}]
    p = tmp_path / "truth.json"
    p.write_text(json.dumps({"effects": items}))
    t = load_truth(p, ModelConfig())
    fx = t.joint_effects
    assert np.allclose(fx.cogging_Nm, [0, 0, 0.4, 0, 0.4, 0, 0]) and np.allclose(fx.cogging_cycles_per_turn, 40)
    assert np.allclose(fx.stiffness_Nm_per_rad, [2e4] * 4 + [5e3] * 3) and np.allclose(fx.backlash_rad, 0.002)
    assert np.allclose(fx.breakaway_Nm, 0.5)
    p.write_text(json.dumps([{"effect": "cogging", "cycles_per_turn": 40}]))
    with pytest.raises(UserError, match="missing 'amplitude_Nm'"):
        load_truth(p, ModelConfig())
    p.write_text(json.dumps([{"effect": "elastic"}, {"effect": "elastic"}]))
    with pytest.raises(UserError, match="elastic given twice"):
        load_truth(p, ModelConfig())
    # the server's plant carries them; RobotState.theta/dtheta report the motor side
    srv = FCIServer(loopback_host(NET), lockstep=True, camera=False, verbose=False, truth=t)
    sim = srv.robot.sim
    assert sim.joint_effects is not None and sim._m.nuser_jnt == plant.ENUSER
    for _ in range(200):
        sim.step()
    st = srv.robot.fill_state().f
    theta, dtheta = sim.motor_state()
    assert np.allclose(st["theta"], theta) and np.allclose(st["dtheta"], dtheta)
    d = np.asarray(st["theta"]) - np.asarray(st["q"])
    assert np.abs(d).max() > 1e-4  # the gravity-loaded joints are deflected (beyond half the gap)
    tau_J = np.asarray(st["tau_J"])
    loaded = np.abs(tau_J) > 1.0
    K = fx.stiffness_Nm_per_rad
    assert np.allclose(d[loaded], (tau_J / K + np.sign(tau_J) * 0.001)[loaded], rtol=1e-3, atol=1e-6)


def _play_generic(tmp_path, truth_items, net, seed=1, period=5.0, periods=2, noise=0.1):
    """A generic excitation (the generators' recipe, rest to rest) played by franka-vs excite's pylibfranka script,
    unmodified in its own process, against serve with the hidden truth; returns the recorded log."""
    import subprocess
    import sys

    from franka_vs_gym.fci import FCIServer
    from franka_vs_gym.validation.excite import Design
    from franka_vs_gym.validation.excite_motion import FourierMotion, generic_playable
    from franka_vs_gym.validation.excite_scripts import scripts
    from franka_vs_gym.validation.loading import load_log

    like = FourierMotion(FER.neutral(), np.zeros((7, 5)), np.zeros((7, 5)), period, periods, 1.0)
    motion = generic_playable(like, seed=seed)
    d = Design(motion, ["payload"], [], "D", [], [], np.zeros(0), np.zeros(0), "", np.zeros(7), 100.0, 0.0, 0)
    play = tmp_path / "play_generic_pylibfranka.py"
    play.write_text(scripts(d, stem="generic")[play.name])
    tf = tmp_path / "truth.json"
    tf.write_text(json.dumps({"effects": truth_items, "torque_noise_Nm": noise, "seed": 3}))
    with FCIServer(loopback_host(net), lockstep=True, camera=False, verbose=False, truth=str(tf)) as srv:
        r = subprocess.run([sys.executable, str(play), srv.host], capture_output=True, text=True, timeout=600,
                           cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    rec = json.loads(r.stdout.strip().splitlines()[-1])
    assert rec["dropped"] == 0
    return load_log(rec["log"])


@pytest.fixture(scope="module")
def clean_diagnosis(tmp_path_factory):
    """The diagnosis of the generic excitation recorded through serve without a hidden truth."""
    from franka_vs_gym.validation.diagnose import diagnose

    return diagnose(_play_generic(tmp_path_factory.mktemp("clean"), [], NET + 2))


def test_cogging_recorded_through_serve_is_flagged_by_the_workbench(tmp_path, clean_diagnosis):
    """serve --truth with cogging on joints 1 and 4 (0.5 Nm, 40 cycles per link turn: a ripple the library has no
    effect for) -> a generic excitation played by a pylibfranka script -> diagnose: the residual is unexplained, on
    those joints, and follows a periodic function of the joint position; without the cogging the same recording is
    explained."""
    from franka_vs_gym.validation.diagnose import diagnose

    cog = [{"effect": "cogging", "amplitude_Nm": 0.5, "cycles_per_turn": 40, "phase_rad": 0.7, "joints": [0, 3]}]
    d = diagnose(_play_generic(tmp_path, cog, NET + 1))
    text = " ".join(d.unexplained.text)
    assert d.unexplained.joints and set(d.unexplained.joints) <= {0, 3}, (d.unexplained.joints, text)
    assert "periodic function of the joint position" in text, text
    assert not clean_diagnosis.unexplained.joints, clean_diagnosis.unexplained.text


def test_elastic_joints_with_backlash_leave_the_link_side_identification_unchanged(tmp_path, clean_diagnosis):
    """Spong's link equation is the rigid one driven by the transmission torque, which the link-side sensor reads:
    a recording of link-side q and tau_J cannot show the elasticity (only theta or the commanded torque could). So
    the workbench must say of an elastic plant with backlash what it says of the rigid one: no effect selected
    beyond those the rigid plant's recording gets (there: a 0.055 Nm s/rad viscous term on joint 2, 0.017 Nm RMS
    against 0.1 Nm of noise, which the elastic recording does not get), nothing unexplained."""
    from franka_vs_gym.validation.diagnose import diagnose

    items = [{"effect": "elastic"}, {"effect": "backlash", "b_rad": 0.003}]
    d = diagnose(_play_generic(tmp_path, items, NET + 4))
    assert not d.unexplained.joints, d.unexplained.text
    assert set(d.selected) <= set(clean_diagnosis.selected), (d.selected, clean_diagnosis.selected)


def test_pylibfranka_client_reads_the_motor_side(tmp_path):
    """A real pylibfranka client (tests/fci_clients/read_state.py, its own process) against serve --truth with
    elastic joints: RobotState.theta is the motor side, theta - q = tau_J / K on the gravity-loaded joints."""
    import subprocess
    import sys
    from pathlib import Path

    pytest.importorskip("pylibfranka")
    from franka_vs_gym.fci import FCIServer

    K = [2e4] * 4 + [5e3] * 3
    tf = tmp_path / "truth.json"
    tf.write_text(json.dumps([{"effect": "elastic", "K": K}]))
    client = Path(__file__).parent / "fci_clients" / "read_state.py"
    with FCIServer(loopback_host(NET + 3), lockstep=True, camera=False, verbose=False, truth=str(tf)) as srv:
        r = subprocess.run([sys.executable, str(client), srv.host], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    st = json.loads(r.stdout.strip().splitlines()[-1])
    q, theta, tau = (np.array(st[k]) for k in ("q", "theta", "tau_J"))
    loaded = np.abs(tau) > 2.0
    assert loaded.sum() >= 2
    assert np.allclose((theta - q)[loaded], (tau / np.array(K))[loaded], rtol=0.02), (theta - q, tau / np.array(K))
