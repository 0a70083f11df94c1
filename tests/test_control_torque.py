"""Torque controllers (computed torque, impedance, gravity compensation, Cartesian computed torque) on FrankaSim.

Each test closes the loop on the MuJoCo plant at 1 kHz and checks a number that a wrong controller would miss:
tracking error with the exact model and its growth when the controller's model lacks friction or a payload, static
stiffness under a known external force, null-space damping of self-motion, gravity compensation holding still.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from franka_vs_gym.control import (
    CartesianComputedTorque,
    CartesianImpedance,
    ComputedTorque,
    GravityCompensation,
    JointImpedance,
    circle_reference,
    null_space_projector,
    pose_error,
)
from franka_vs_gym.experiments.tracking import Q0, desired_trajectory, pid_gains, run_tracking
from franka_vs_gym.model import FrankaModel, ModelConfig
from franka_vs_gym.model.config import Friction, RigidBody
from franka_vs_gym.policies import ComputedTorquePolicy, JointImpedancePolicy
from franka_vs_gym.sim.robot import FORCE_TORQUE, JOINT_STATE, FrankaSim


def _loop(sim: FrankaSim, n: int, tau_fn) -> None:
    for _ in range(n):
        sim.set_force_torque(JOINT_STATE, tau_fn(sim.time, sim.get_position(), sim.get_velocity()))
        sim.step()


def _steady_rmse(r, t_from: float) -> np.ndarray:
    sel = r.time >= t_from
    return np.sqrt(np.mean(r.error[sel] ** 2, axis=0))


# ---------------------------------------------------------------------------------------------- computed torque
@pytest.fixture(scope="module")
def tracking_runs():
    return {me: run_tracking(3.5, model_error=me, progress=False) for me in ("none", "no-friction", "payload")}


def test_computed_torque_tracks_with_exact_model(tracking_runs):
    r = tracking_runs["none"]
    rmse = _steady_rmse(r, 2.0)
    # sinusoids of 0.4-0.5 rad on joints 1, 3, 4; once the smooth start has faded the error is below 1 mrad
    assert rmse.max() < 1.5e-3, rmse
    # and the start is smooth: the first command is zero (tau - tau0)
    assert np.abs(r.tau_cmd[0]).max() < 1e-9


def test_computed_torque_degrades_without_friction_model(tracking_runs):
    exact, nofric = _steady_rmse(tracking_runs["none"], 2.0), _steady_rmse(tracking_runs["no-friction"], 2.0)
    # friction of the published FER (up to ~0.5-1 Nm) goes uncompensated: the error grows on the moving and
    # the low-inertia wrist joints
    assert np.linalg.norm(nofric) > 2.0 * np.linalg.norm(exact), (exact, nofric)
    assert nofric[5] > 5.0 * exact[5]


def test_computed_torque_degrades_with_unknown_payload(tracking_runs):
    exact, payload = _steady_rmse(tracking_runs["none"], 2.0), _steady_rmse(tracking_runs["payload"], 2.0)
    # an undeclared 1 kg in the gripper loads the wrist (joints 5, 6) with gravity nobody compensates
    assert payload[4] > 10 * exact[4] and payload[5] > 10 * exact[5], (exact, payload)
    assert payload[4] > 5e-3


def test_pid_gains_place_the_poles():
    kd, ki = pid_gains([400.0] * 6 + [900.0], integral_rate=4.0)
    for i in (0, 6):
        kp = 400.0 if i == 0 else 900.0
        roots = np.roots([1.0, kd[i], kp, ki[i]])
        w = math.sqrt(16 + kp) - 4
        assert np.allclose(np.sort(roots.real), np.sort([-4.0, -w, -w]), atol=1e-3)
        assert np.abs(roots.imag).max() < 1e-2


# ---------------------------------------------------------------------------------------------- gravity compensation
def test_gravity_compensation_holds_an_undeclared_payload():
    payload = RigidBody(1.0, (0.0, 0.0, 0.1), np.eye(3) * 1e-3)
    # the uncompensated payload makes the arm fall past the velocity limit: plant physics, reflexes off
    sim = FrankaSim(camera=False, q0=Q0, undeclared_payload=payload, reflexes=False)
    knows = FrankaModel(sim.model.config.copy(payload=payload))
    for ctrl, should_hold in ((GravityCompensation(sim.model, internal=sim.model), False),
                              (GravityCompensation(knows, internal=sim.model), True)):
        sim.reset(Q0)
        sim.set_robot_state(FORCE_TORQUE)
        _loop(sim, 800, lambda t, q, dq, c=ctrl: c(q, dq))
        drift = np.abs(sim.get_position() - Q0).max()
        if should_hold:
            assert drift < 1e-6, drift
        else:
            assert drift > 0.05, drift


def test_gravity_compensation_damping_and_input_checks():
    m = FrankaModel()
    gc = GravityCompensation(m, kd=2.0)
    dq = np.linspace(-1, 1, 7)
    assert np.allclose(gc(Q0, dq), -2.0 * dq)
    with pytest.raises(ValueError, match="dq"):
        gc(Q0, np.zeros(6))
    with pytest.raises(ValueError, match="kd"):
        GravityCompensation(m, kd=-1.0)
    with pytest.raises(ValueError, match="FrankaModel"):
        GravityCompensation("not a model")


# ---------------------------------------------------------------------------------------------- joint impedance
def _hand_force(sim: FrankaSim, force: np.ndarray, at_ee: bool) -> int:
    m, d = sim.world.model, sim.world.data
    hb = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{sim.prefix}hand")
    d.xfrc_applied[hb, :3] = force
    if at_ee:  # the same force acting at the end-effector point: add the moment about the body's CoM
        ee = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, f"{sim.prefix}ee")
        d.xfrc_applied[hb, 3:] = np.cross(d.site_xpos[ee] - d.xipos[hb], force)
    return hb


def test_joint_impedance_static_stiffness_under_external_force():
    sim = FrankaSim(camera=False, q0=Q0)
    sim.set_robot_state(FORCE_TORQUE)
    k = np.array([600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0])
    ji = JointImpedance(sim.model, k=k)
    F = np.array([10.0, -5.0, 8.0])
    m, d = sim.world.model, sim.world.data
    hb = _hand_force(sim, F, at_ee=False)
    _loop(sim, 2500, lambda t, q, dq: ji(q, dq, Q0))
    # external joint torque from MuJoCo's own Jacobian of the loaded body's CoM (independent of pinocchio)
    jacp = np.zeros((3, m.nv))
    mujoco.mj_jacBodyCom(m, d, jacp, None, hb)
    tau_ext = jacp[:, sim._vs].T @ F
    dq_meas = sim.get_position() - Q0
    assert np.abs(sim.get_velocity()).max() < 1e-6
    assert np.allclose(dq_meas, tau_ext / k, rtol=0.02, atol=2e-5), (dq_meas, tau_ext / k)
    d.xfrc_applied[:] = 0.0


def test_joint_impedance_terms():
    m = FrankaModel()
    ji = JointImpedance(m, k=100.0, d=10.0, coriolis=False)
    q_d = Q0 + 0.01
    assert np.allclose(ji(Q0, np.zeros(7), q_d), 1.0)
    B = m.mass_matrix(Q0)
    ddq = np.linspace(-1, 1, 7)
    assert np.allclose(ji(Q0, np.zeros(7), Q0, None, ddq), B @ ddq)
    crit = JointImpedance(m, k=100.0)
    assert np.allclose(crit.damping(Q0), 2 * np.sqrt(100.0 * np.diag(B)))
    with pytest.raises(ValueError, match="q_d"):
        ji(Q0, np.zeros(7), np.full(7, np.nan))


# ---------------------------------------------------------------------------------------------- Cartesian impedance
def test_pose_error_matches_pinocchio_log():
    m = FrankaModel()
    rng = np.random.default_rng(3)
    for _ in range(5):
        M = m.fMe(Q0 + rng.normal(0, 0.3, 7)).copy()
        Md = m.fMe(Q0 + rng.normal(0, 0.3, 7)).copy()
        e = pose_error(M, Md)
        assert np.allclose(e[:3], Md[:3, 3] - M[:3, 3])
        assert np.allclose(e[3:], pin.log3(Md[:3, :3] @ M[:3, :3].T), atol=1e-9)
    Rpi = pin.exp3(np.array([0.0, math.pi - 1e-6, 0.0]))
    Md = np.eye(4)
    Md[:3, :3] = Rpi
    assert np.allclose(np.abs(pose_error(np.eye(4), Md)[3:]), [0, math.pi - 1e-6, 0], atol=1e-4)


def test_cartesian_impedance_static_stiffness():
    sim = FrankaSim(camera=False, q0=Q0)
    sim.set_robot_state(FORCE_TORQUE)
    ci = CartesianImpedance(sim.model, k_translation=[500.0, 800.0, 400.0], k_rotation=30.0)
    M0 = sim.get_fMe()
    F = np.array([10.0, -8.0, 6.0])
    d = sim.world.data
    for _ in range(3000):
        _hand_force(sim, F, at_ee=True)
        sim.set_force_torque(JOINT_STATE, ci(sim.get_position(), sim.get_velocity(), M0))
        sim.step()
    d.xfrc_applied[:] = 0.0
    dx = sim.get_fMe()[:3, 3] - M0[:3, 3]
    assert np.allclose(dx, F / np.array([500.0, 800.0, 400.0]), rtol=0.02), dx
    # a pure force at e leaves the orientation where it was
    assert np.abs(pose_error(sim.get_fMe(), M0)[3:]).max() < 1e-4


def test_cartesian_impedance_nullspace_damping_stops_self_motion():
    sim = FrankaSim(camera=False, q0=Q0, friction=False)
    J = sim.model.fJe(Q0)
    n = np.linalg.svd(J)[2][-1]  # the self-motion direction of the redundant arm at Q0
    dq0 = 0.5 * n / np.abs(n).max()
    M0 = sim.get_fMe()
    speed = {}
    for dn in (0.0, 5.0):
        sim.reset(Q0, dq0)
        sim.set_robot_state(FORCE_TORQUE)
        ci = CartesianImpedance(sim.model, nullspace_damping=dn)
        _loop(sim, 1000, lambda t, q, dq, c=ci: c(q, dq, M0))
        speed[dn] = np.linalg.norm(sim.get_velocity())
        assert np.linalg.norm(pose_error(sim.get_fMe(), M0)) < 5e-3
    assert speed[0.0] > 0.2  # undamped: the arm keeps swinging in its null space
    assert speed[5.0] < 1e-2 * speed[0.0], speed


def test_null_space_projector_is_dynamically_consistent():
    m = FrankaModel()
    N, Lam = null_space_projector(m, Q0)
    J, B = m.fJe(Q0), m.mass_matrix(Q0)
    # torques N^T tau0 produce no end-effector acceleration: J B^-1 N^T = 0
    assert np.abs(J @ np.linalg.solve(B, N.T)).max() < 1e-9
    assert np.allclose(N @ N, N, atol=1e-9)
    assert np.allclose(Lam, np.linalg.inv(J @ np.linalg.solve(B, J.T)), rtol=1e-6)


# ---------------------------------------------------------------------------------------------- Cartesian CT
def _circle_rms(true_cfg: ModelConfig, ctrl_model: FrankaModel | None, seconds: float = 2.5) -> float:
    sim = FrankaSim(true_cfg, camera=False, q0=Q0)
    sim.set_robot_state(FORCE_TORQUE)
    ctrl = CartesianComputedTorque(ctrl_model or sim.model, mu=4.0)
    M0 = sim.get_fMe()
    errs = []
    for _ in range(int(seconds / sim.dt)):
        t = sim.time
        p, dp, ddp = circle_reference(t, M0[:3, 3], 0.05, 0.3, ramp=1.0)
        Md = M0.copy()
        Md[:3, 3] = p
        tau = ctrl(t, sim.get_position(), sim.get_velocity(), Md, np.r_[dp, 0, 0, 0], np.r_[ddp, 0, 0, 0])
        sim.set_force_torque(JOINT_STATE, tau)
        sim.step()
        errs.append(np.linalg.norm(sim.get_fMe()[:3, 3] - circle_reference(sim.time, M0[:3, 3], 0.05, 0.3,
                                                                            ramp=1.0)[0]))
    e = np.array(errs)[500:]
    return float(np.sqrt(np.mean(e**2)))


def test_cartesian_computed_torque_tracks_a_circle():
    exact = _circle_rms(ModelConfig(), None)
    nofric = _circle_rms(ModelConfig(), FrankaModel(ModelConfig(friction=Friction.none())))
    assert exact < 2e-4, exact  # 5 cm circle at 0.3 Hz within 0.2 mm
    assert nofric > 5 * exact, (exact, nofric)


def test_circle_reference_derivatives():
    start = np.array([0.4, 0.1, 0.5])
    h = 1e-5
    for t in (0.3, 0.99, 1.7):
        p, dp, ddp = circle_reference(t, start, 0.05, 0.3, ramp=1.0)
        pp, dpp, _ = circle_reference(t + h, start, 0.05, 0.3, ramp=1.0)
        pm, dpm, _ = circle_reference(t - h, start, 0.05, 0.3, ramp=1.0)
        assert np.allclose((pp - pm) / (2 * h), dp, atol=1e-6)
        assert np.allclose((dpp - dpm) / (2 * h), ddp, atol=1e-5)
    p0, dp0, _ = circle_reference(0.0, start, 0.05, 0.3, ramp=1.0)
    assert np.allclose(p0, start) and np.allclose(dp0, 0)
    # after the ramp every point is at distance r from the centre start - r u
    p, _, _ = circle_reference(5.0, start, 0.05, 0.3, ramp=1.0)
    assert abs(np.linalg.norm(p - (start - 0.05 * np.array([0, 1, 0]))) - 0.05) < 1e-12
    with pytest.raises(ValueError, match="radius"):
        circle_reference(0.0, start, -0.05, 0.3)


def test_cartesian_controllers_reject_bad_poses():
    m = FrankaModel()
    with pytest.raises(ValueError, match="fMe_d"):
        CartesianComputedTorque(m)(0.0, Q0, np.zeros(7), np.ones((4, 4)))
    with pytest.raises(ValueError, match="fMe_d"):
        CartesianImpedance(m)(Q0, np.zeros(7), np.eye(3))
    with pytest.raises(ValueError, match="q_nullspace"):
        CartesianImpedance(m, nullspace_stiffness=1.0)


# ---------------------------------------------------------------------------------------------- policies
def _obs(sim: FrankaSim, t: float) -> dict[str, np.ndarray]:
    q_d, dq_d, ddq_d = desired_trajectory(t)
    f = np.float32
    return {"q": sim.get_position().astype(f), "dq": sim.get_velocity().astype(f), "q_desired": q_d.astype(f),
            "dq_desired": dq_d.astype(f), "ddq_desired": ddq_d.astype(f), "time": np.array([t], f)}


@pytest.mark.parametrize("policy_cls, tol", [(ComputedTorquePolicy, 4e-3), (JointImpedancePolicy, 2e-2)])
def test_torque_policies_track_on_the_observation_contract(policy_cls, tol):
    sim = FrankaSim(camera=False, q0=Q0)
    policy = policy_cls(sim.model)
    for _episode in range(2):  # the second episode checks the reset on episode_start
        sim.reset(Q0)
        sim.set_robot_state(FORCE_TORQUE)
        errs = []
        for k in range(1500):
            t = k * sim.dt
            obs = _obs(sim, t)
            action, state = policy.predict(obs, episode_start=np.array([k == 0]))
            assert state is None and action.dtype == np.float32 and action.shape == (7,)
            if k == 0 and policy_cls is ComputedTorquePolicy:
                assert np.abs(action).max() < 1e-6  # smooth start: tau - tau0 = 0 at t0
            sim.set_force_torque(JOINT_STATE, action)
            sim.step()
            errs.append(np.abs(desired_trajectory((k + 1) * sim.dt)[0] - sim.get_position()).max())
        assert max(errs[1000:]) < tol, max(errs[1000:])


def test_computed_torque_policy_equals_controller_and_checks_input():
    m = FrankaModel()
    policy = ComputedTorquePolicy(m, mu=0.0, clip=False)
    ctrl = ComputedTorque(m, mu=0.0)
    sim = FrankaSim(camera=False, q0=Q0 + 0.01)
    obs = _obs(sim, 0.2)
    a, _ = policy.predict(obs)
    ref = ctrl(0.2, *(np.asarray(obs[k], np.float64) for k in ("q", "dq", "q_desired", "dq_desired",
                                                                "ddq_desired")))
    assert np.allclose(a, ref, rtol=1e-5, atol=1e-4)
    bad = dict(obs)
    del bad["ddq_desired"]
    with pytest.raises(ValueError, match="ddq_desired"):
        policy.predict(bad)
    bad = dict(obs, q=np.zeros(6, np.float32))
    with pytest.raises(ValueError, match="'q'"):
        policy.predict(bad)
    with pytest.raises(ValueError, match="dict"):
        policy.predict(np.zeros(7))
    clipped = ComputedTorquePolicy(m, kp=1e6, mu=0.0)
    far = dict(obs, q_desired=(obs["q"] + 1.0).astype(np.float32))
    a, _ = clipped.predict(far)
    assert np.all(np.abs(a) <= FrankaModel.limits()["tau_max"] + 1e-4)


@pytest.mark.parametrize("policy_cls", [ComputedTorquePolicy, JointImpedancePolicy])
@pytest.mark.parametrize("control_period", [0.001, 0.01])
def test_torque_policies_succeed_on_the_tracking_env(policy_cls, control_period):
    gym = pytest.importorskip("gymnasium")
    import franka_vs_gym.envs  # noqa: F401  (registers the environments)

    env = gym.make("FrankaTorqueTracking-v0", control_period=control_period, time_limit=2.0)
    # the policy acts in the env's normalized action space (its torque divided by the env's torque scale)
    policy = policy_cls(env.unwrapped.sim.model).with_action_scale(env.unwrapped.action_scale)
    obs, _ = env.reset(seed=1)
    start, done = True, False
    while not done:
        action, _ = policy.predict(obs, episode_start=np.array([start]))
        start = False
        assert env.action_space.contains(action)
        obs, _, term, trunc, info = env.step(action)
        done = term or trunc
    env.close()
    assert not term and info["is_success"], info
    assert info["rms_error"] < 5e-3


def test_computed_torque_rejects_bad_input():
    ctrl = ComputedTorque(FrankaModel())
    z = np.zeros(7)
    with pytest.raises(ValueError, match="q_d"):
        ctrl(0.0, Q0, z, np.zeros(6), z, z)
    with pytest.raises(ValueError, match="ddq_d"):
        ctrl(0.0, Q0, z, Q0, z, np.full(7, np.inf))
    with pytest.raises(ValueError, match="kp"):
        ComputedTorque(FrankaModel(), kp=-1.0)


def test_cartesian_computed_torque_compensates_an_undeclared_payload():
    payload = RigidBody(0.8, np.array([0.0, 0.0, 0.1]), np.eye(3) * 1e-3)

    def hold_error(knows_payload: bool) -> float:
        sim = FrankaSim(camera=False, q0=Q0, undeclared_payload=payload)
        sim.set_robot_state(FORCE_TORQUE)
        model = FrankaModel(sim.model.config.copy(payload=payload)) if knows_payload else sim.model
        ctrl = CartesianComputedTorque(model, internal=sim.model)
        M0 = sim.get_fMe()
        _loop(sim, 1500, lambda t, q, dq: ctrl(t, q, dq, M0))
        return float(np.linalg.norm(sim.get_fMe()[:3, 3] - M0[:3, 3]))

    sag, held = hold_error(False), hold_error(True)
    assert sag > 1e-3, sag  # the robot's gravity compensation ignores the 0.8 kg: the hand sags by millimetres
    assert held < 1e-5, held  # with the payload in the controller's model (and the robot's as internal) it holds


def test_joint_impedance_natural_frequency_and_fixed_stiffness_at_100_hz():
    """The inertia-scaled default is stable under a 100 Hz hold; libfranka's fixed wrist stiffness is not."""
    m = FrankaModel()
    ji = JointImpedance(m, natural_frequency=10.0)
    B = np.diag(m.mass_matrix(Q0))
    assert np.allclose(ji.stiffness(Q0), 100.0 * B) and np.allclose(ji.damping(Q0), 20.0 * B)
    with pytest.raises(ValueError, match="natural_frequency"):
        JointImpedance(m, natural_frequency=0.0)

    def hold(policy) -> tuple[float, float]:
        """(final position error, max joint speed over the last half second), holding Q0 from Q0 + 0.05 rad."""
        # the chattering wrist passes its velocity limit: plant physics, reflexes off
        sim = FrankaSim(camera=False, q0=Q0 + 0.05, friction=False, reflexes=False)
        sim.set_robot_state(FORCE_TORQUE)
        z = np.zeros(7, np.float32)
        speed = 0.0
        for k in range(100):  # 1 s at 100 Hz: the torque is held for 10 physics steps
            obs = {"q": sim.get_position().astype(np.float32), "dq": sim.get_velocity().astype(np.float32),
                   "q_desired": Q0.astype(np.float32), "dq_desired": z, "ddq_desired": z,
                   "time": np.array([k * 0.01], np.float32)}
            sim.set_force_torque(JOINT_STATE, policy.predict(obs)[0])
            for _ in range(10):
                sim.step()
            if k >= 50:
                speed = max(speed, float(np.abs(sim.get_velocity()).max()))
        return float(np.abs(sim.get_position() - Q0).max()), speed

    err, speed = hold(JointImpedancePolicy(m))
    assert err < 2e-3 and speed < 0.1, (err, speed)
    _, speed_fixed = hold(JointImpedancePolicy(m, k=JointImpedance.DEFAULT_K))
    assert speed_fixed > 1.0, speed_fixed  # the stiff light wrist joints chatter under the 100 Hz hold
