"""The FrankaSim paper experiments end to end, in reduced form: `franka-vs experiment tracking` and `dual-arm`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from franka_vs_gym.cli import main as cli_main
from franka_vs_gym.experiments import dual_arm as D
from franka_vs_gym.experiments.common import make_run_dir
from franka_vs_gym.experiments.tracking import Q0, desired_trajectory, run_tracking, to_measurement_log
from franka_vs_gym.model.geometry import homogeneous


def _only_run(tmp_path, prefix):
    runs = sorted(p for p in tmp_path.iterdir() if p.name.startswith(prefix))
    assert runs, list(tmp_path.iterdir())
    return runs


# ---------------------------------------------------------------------------------------------- tracking (IV-A)
def test_tracking_cli_writes_plots_metrics_and_a_workbench_log(tmp_path, capsys):
    from franka_vs_gym.validation.loading import load_log

    args = ["experiment", "tracking", "--duration", "1.2", "--out", str(tmp_path), "--no-video", "--quiet"]
    assert cli_main(args) == 0
    (run,) = _only_run(tmp_path, "tracking-")
    for name in ("positions.png", "torques.png", "errors.png", "metrics.json", "log.npz", "log.npz.json"):
        assert (run / name).is_file(), name
    m = json.loads((run / "metrics.json").read_text())
    assert len(m["rmse_rad"]) == 7 and m["rate_hz"] == 1000.0
    # exact model: tracking within a few mrad even through the smooth start
    assert max(m["rmse_rad"]) < 0.02
    log = load_log(run / "log.npz")
    assert log.n == 1200
    assert np.allclose(log.q[0], Q0)
    assert np.allclose(log.q_d[-1], desired_trajectory(log.time[-1])[0])
    # tau_J holds gravity (the robot's g(q) added to the gravity-free command): at rest at t0 it is g(q0)
    from franka_vs_gym.model import FrankaModel

    assert np.allclose(log.tau_J[0], FrankaModel().gravity(Q0) + log.tau_J_d[0], atol=0.05)
    assert log.controller["law"] == "computed_torque_eq2"
    assert "RMSE" in capsys.readouterr().out
    # a second run never reuses the folder
    assert cli_main(args) == 0
    assert len(_only_run(tmp_path, "tracking-")) == 2


def test_tracking_video_and_model_error_option(tmp_path):
    args = ["experiment", "tracking", "--duration", "0.3", "--out", str(tmp_path), "--quiet",
            "--model-error", "no-friction", "--log-format", "csv"]
    assert cli_main(args) == 0
    (run,) = _only_run(tmp_path, "tracking-")
    assert (run / "video.mp4").stat().st_size > 1000
    assert (run / "log.csv").is_file()
    assert json.loads((run / "metrics.json").read_text())["settings"]["model_error"] == "no-friction"


def test_tracking_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError, match="duration"):
        run_tracking(0.0, progress=False)
    with pytest.raises(ValueError, match="model_error"):
        run_tracking(0.1, model_error="gravity", progress=False)
    # the CLI refuses bad values with a usage error (argparse exit code 2) ...
    with pytest.raises(SystemExit) as e:
        cli_main(["experiment", "tracking", "--duration", "-1", "--out", str(tmp_path)])
    assert e.value.code == 2
    # ... and an --out that is a file with a clear error and exit code 2
    blocker = tmp_path / "afile"
    blocker.write_text("x")
    assert cli_main(["experiment", "tracking", "--duration", "0.1", "--out", str(blocker), "--quiet"]) == 2


def test_measurement_log_of_a_run_round_trips(tmp_path):
    from franka_vs_gym.validation.loading import load_log
    from franka_vs_gym.validation.logs import save_log

    r = run_tracking(0.2, progress=False)
    p = save_log(to_measurement_log(r), tmp_path / "x.csv")
    back = load_log(p)
    assert np.allclose(back.q, r.q, atol=1e-8) and np.allclose(back.tau_J, r.tau_J, atol=1e-6)


def test_make_run_dir_never_reuses(tmp_path):
    a = make_run_dir("x", root=tmp_path)
    b = make_run_dir("x", root=tmp_path)
    assert a != b and a.is_dir() and b.is_dir()


# ---------------------------------------------------------------------------------------------- dual arm (IV-B)
@pytest.fixture(scope="module")
def dual_runs():
    kw = dict(gc_time=0.3, reach_time=0.7, circle_ramp=0.5, progress=False)
    return {obstacle: D.run_dual_arm(3.3, obstacle=obstacle, **kw) for obstacle in (True, False)}


def test_dual_arm_left_arm_holds_then_tracks_the_circle(dual_runs):
    m = dual_runs[True].metrics()
    # gravity compensation (arm + hand by the robot, the undeclared tag holder by the controller): no drift
    assert m["gravity_compensation_drift_m"] < 1e-5
    # Cartesian computed torque with the payload in its model: 5 cm circle within 0.5 mm
    assert m["circle_rmse_m"] < 5e-4, m["circle_rmse_m"]


def test_dual_arm_pbvs_converges_and_follows(dual_runs):
    run = dual_runs[False]
    free = run.metrics()
    # during gravity compensation (tag still) PBVS shrinks the initial 2.7 cm / 3.3 deg offset as exp(-6 t)
    e0 = np.linalg.norm(run.pbvs_error[0, :3])
    assert 0.02 < e0 < 0.035
    assert free["pbvs_final_translation_error_before_motion_m"] < 0.25 * e0
    # following the moving tag at 30 Hz without contact: centred at 0.20 m within about a centimetre
    assert free["pbvs_translation_rmse_m"] < 0.012, free["pbvs_translation_rmse_m"]
    assert free["contact_force_peak_n"] == 0.0 and free["tag_visible_fraction"] == 1.0


def test_dual_arm_obstacle_bends_the_path_into_a_d(dual_runs):
    with_obs, free = dual_runs[True], dual_runs[False]
    m = with_obs.metrics()
    assert m["contact_force_peak_n"] > 2.0 and m["contact_time_s"] > 0.05
    # the contact is on the hand (not the arm behind the sensor), so the wrist F/T sensor sees it too
    touched = set(with_obs.settings["bodies_touching_obstacle"])
    assert touched and touched <= {"right_hand", "right_hand_geoms", "right_leftfinger", "right_rightfinger"}, touched
    assert m["ft_force_peak_n"] > 0.5 * m["contact_force_peak_n"]
    # the free path dips below where the obstacle stops the gripper: the obstacle flattens the bottom ("D")
    zmin_free = free.metrics()["right_path_min_z_m"]
    assert m["right_path_min_z_m"] > zmin_free + 0.005, (m["right_path_min_z_m"], zmin_free)
    # ... while PBVS is worse in contact than when free
    assert m["pbvs_translation_rmse_contact_m"] > m["pbvs_translation_rmse_free_m"]


def test_dual_arm_cli_end_to_end(tmp_path):
    args = ["experiment", "dual-arm", "--duration", "0.25", "--out", str(tmp_path), "--quiet"]
    assert cli_main(args) == 0
    (run,) = _only_run(tmp_path, "dual-arm-")
    for name in ("video.mp4", "paths.png", "contact_force.png", "pbvs_error.png", "metrics.json", "timeseries.npz"):
        assert (run / name).is_file(), name
    m = json.loads((run / "metrics.json").read_text())
    assert m["video_frames"] >= 6 and m["settings"]["camera_rate_hz"] == 30.0


def test_dual_arm_detected_tag_pose_matches_the_true_one():
    world, left, right, _ = D.build_world()
    meas = D._TagMeasurement(world, right, "detect")
    cMo, img = meas.measure()
    assert img is not None and cMo is not None
    true = meas.true_cMo()
    assert np.linalg.norm(cMo[:3, 3] - true[:3, 3]) < 5e-3
    world.close()


def test_dual_arm_rejects_bad_input():
    with pytest.raises(ValueError, match="camera_rate"):
        D.run_dual_arm(1.0, camera_rate=0.0, progress=False)
    with pytest.raises(ValueError, match="vision"):
        D.run_dual_arm(1.0, vision="magic", progress=False)
    with pytest.raises(ValueError, match="admittance"):
        D.run_dual_arm(1.0, admittance=-1.0, progress=False)


def test_pbvs_twist_decreases_the_error_and_follows_a_moving_tag():
    from franka_vs_gym.vision.features import pbvs_features

    cMo = homogeneous(D._exp(np.array([0.05, -0.1, 0.2])) @ D.cdMo[:3, :3], [0.02, -0.01, 0.25])
    dt, gain = 1e-3, 2.0

    def step(v, cMo_, tag_shift=(0.0, 0.0, 0.0)):
        """cMo after the camera moves with twist v (in c) for dt while the tag translates by tag_shift (in c)."""
        cMc2 = homogeneous(D._exp(v[3:] * dt), v[:3] * dt)
        moved = cMo_.copy()
        moved[:3, 3] += np.asarray(tag_shift)
        return np.linalg.inv(cMc2) @ moved

    e0 = pbvs_features(cMo, D.cdMo)[0]
    e1 = pbvs_features(step(D.pbvs_twist(cMo, D.cdMo, gain), cMo), D.cdMo)[0]
    assert np.allclose(e1, e0 * (1 - gain * dt), atol=2e-6)
    # a tag translating at v_o (in c): with v_o as feed-forward the error decays as if the tag stood still
    v_o = np.array([0.05, -0.08, 0.02])
    e_ff = pbvs_features(step(D.pbvs_twist(cMo, D.cdMo, gain, v_o), cMo, v_o * dt), D.cdMo)[0]
    e_noff = pbvs_features(step(D.pbvs_twist(cMo, D.cdMo, gain), cMo, v_o * dt), D.cdMo)[0]
    assert np.allclose(e_ff, e1, atol=2e-6)
    assert np.abs(e_noff - e1).max() > 20 * np.abs(e_ff - e1).max()
    with pytest.raises(ValueError, match="gain"):
        D.pbvs_twist(cMo, D.cdMo, 0.0)


def test_workbench_diagnoses_the_unknown_payload_of_a_simulated_run():
    """A peer's checker: the validation workbench, given the tracking log with an undeclared 1 kg payload,
    names the payload as what the model lacks (and finds nothing large on the exact run's log)."""
    from franka_vs_gym.validation.diagnose import diagnose

    payload_run = to_measurement_log(run_tracking(4.0, model_error="payload", progress=False))
    d = diagnose(payload_run)
    assert d.verdict == "payload", d.verdict
    assert d.rmse_tau_total > 0.5  # Nm: the payload's gravity and inertia are in the measured torques
    exact = diagnose(to_measurement_log(run_tracking(4.0, progress=False)))
    assert exact.rmse_tau_total < 0.01  # the simulated robot is the published model: nothing to explain


def test_dual_arm_pixel_noise_is_seeded():
    kw = dict(pixel_noise=0.5, gc_time=0.5, progress=False)
    a = D.run_dual_arm(0.4, seed=3, **kw)
    b = D.run_dual_arm(0.4, seed=3, **kw)
    c = D.run_dual_arm(0.4, seed=4, **kw)
    assert np.array_equal(a.right_ee, b.right_ee)
    assert not np.array_equal(a.right_ee, c.right_ee)
    with pytest.raises(ValueError, match="pixel noise"):
        D.run_dual_arm(0.1, pixel_noise=-1.0, progress=False)
