"""franka-vs excite (the designed excitation) and franka-vs serve --truth (a plant the robot's model does not know),
end to end: design -> serve with a hidden payload -> the generated pylibfranka script, unmodified, in its own
process -> diagnose and fit the recording."""

import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import loopback_host

from franka_vs_gym.model.config import ModelConfig
from franka_vs_gym.model.franka_model import FrankaModel
from franka_vs_gym.validation.excite import Design, design_excitation, effect_widths
from franka_vs_gym.validation.excite_information import motion_information, predicted_widths
from franka_vs_gym.validation.excite_motion import FourierMotion, generic_motion, generic_playable
from franka_vs_gym.validation.excite_scripts import scripts, trajectory_table

NET = 231  # this file's loopback nets (conftest.loopback_host)


def _random_motion(rng, L=5):
    return FourierMotion(FrankaModel().config.robot.neutral(), rng.normal(0, 0.05, (7, L)),
                         rng.normal(0, 0.05, (7, L)), 6.0, 2, 1.0).constrained()


def test_motion_starts_and_ends_at_rest_and_its_derivatives_are_consistent():
    m = _random_motion(np.random.default_rng(3))
    rows = trajectory_table(m, 1000.0)
    t, q, dq, ddq = rows[:, 0], rows[:, 1:8], rows[:, 8:15], rows[:, 15:22]
    # at rest at both ends and during the rests
    for k in (0, -1):
        assert np.allclose(dq[k], 0) and np.allclose(ddq[k], 0)
    inside = (t > m.rest + 0.01) & (t < m.duration - m.rest - 0.01)
    assert np.abs(dq[inside]).max() > 0.05
    # the analytic velocity and acceleration against numerical derivatives of the sampled position (independent)
    assert np.allclose(np.gradient(q, t, axis=0)[1:-1], dq[1:-1], atol=2e-5)
    # (the jerk steps where the motion leaves a rest: a central difference there is off by jerk x dt / 2)
    assert np.allclose(np.gradient(dq, t, axis=0)[1:-1], ddq[1:-1], atol=1e-3 * np.abs(ddq).max())
    # leaving the rest is smooth: velocity and acceleration continuous at the junctions
    j = int(np.searchsorted(t, m.rest))
    assert np.abs(dq[j - 2:j + 3]).max() < 1e-3 and np.abs(ddq[j - 2:j + 3]).max() < 0.2


def test_offset_width_is_the_white_noise_formula():
    """A torque offset's column is 1: its predicted 95 % width is 2 x 1.96 sigma / sqrt(duration x neff_rate)."""
    from franka_vs_gym.validation.effects import get_effect

    sig = np.array([0.3, 0.25, 0.2, 0.2, 0.1, 0.08, 0.05])
    m = _random_motion(np.random.default_rng(4))
    F, cols = motion_information(m, ModelConfig(), [get_effect("torque_offset")], sig)
    w = predicted_widths(F, 50.0)
    assert np.allclose(w, 2 * 1.959964 * sig / np.sqrt(m.duration * 50.0), rtol=1e-6)
    assert cols.names == [f"torque_offset[{j}]" for j in range(7)]


def test_unseen_direction_is_infinite_not_narrow():
    """Viscous friction and a per-joint Coulomb step are both zero on a joint that never moves: no finite width."""
    from franka_vs_gym.validation.effects import get_effect

    m = _random_motion(np.random.default_rng(5))
    m.a[6] = 0.0
    m.b[6] = 0.0
    F, cols = motion_information(m, ModelConfig(), [get_effect("viscous_friction")], np.full(7, 0.2))
    w = predicted_widths(F, 100.0)
    assert np.isinf(w[6]) and np.isfinite(w[:6]).all()


def test_design_keeps_limits_and_table_clearance_and_beats_generic():
    d = design_excitation(["armature"], duration=14.0, time_budget=120.0, max_evaluations=250, fraction=0.5,
                          clearance=0.15, seed=1)
    model = FrankaModel()
    lim = model.limits()
    rows = trajectory_table(d.motion, 1000.0)
    t, q = rows[:, 0], rows[:, 1:8]
    # limits checked independently: numerical derivatives of the sampled positions
    dq = np.gradient(q, t, axis=0)
    ddq = np.gradient(dq, t, axis=0)
    dddq = np.gradient(ddq, t, axis=0)
    assert (q >= lim["q_min"] + 0.2 - 1e-9).all() and (q <= lim["q_max"] - 0.2 + 1e-9).all()
    assert (np.abs(dq) <= 0.5 * lim["dq_max"] * 1.001).all()
    assert (np.abs(ddq[2:-2]) <= 0.5 * lim["ddq_max"] * 1.01).all()
    assert (np.abs(dddq[3:-3]) <= 0.5 * lim["dddq_max"] * 1.05).all()
    # the flange (FrankaModel's own kinematics) stays 0.15 m over the table top
    z = np.array([model.fMfl(qk)[2, 3] for qk in q[::50]])
    assert z.min() >= 0.15 - 1e-6
    assert d.summary()[0]["median_width_ratio_reference_over_designed"] > 1.5
    assert np.all(np.isfinite(d.widths))


def _cli(capsys, *argv):
    from franka_vs_gym.cli import main as cli_main

    rc = cli_main(list(argv))
    return rc, capsys.readouterr().err


def test_cli_errors_are_one_line(tmp_path, capsys):
    rc, err = _cli(capsys, "excite", "--effects", "no_such_effect", "-o", str(tmp_path / "x"))
    assert rc == 2 and "unknown effect 'no_such_effect'" in err and len(err.strip().splitlines()) == 1
    rc, err = _cli(capsys, "excite", "--separate", "payload", "-o", str(tmp_path / "x"))
    assert rc == 2 and "--separate needs two or more effects" in err
    diag = tmp_path / "d.json"
    diag.write_text(json.dumps({"selected": [], "verdict": "none"}))
    rc, err = _cli(capsys, "excite", "--from", str(diag), "-o", str(tmp_path / "x"))
    assert rc == 2 and "names no ambiguous or selected effect" in err
    assert not (tmp_path / "x").exists()


def test_question_from_a_diagnosis(tmp_path):
    from franka_vs_gym.validation.cli_excite import question_from

    p = tmp_path / "diag.json"
    p.write_text(json.dumps({"selected": [{"effect": "payload"}],
                             "ambiguous": [["coulomb_friction", "torque_offset"]]}))
    assert question_from(str(p)) == ([], [["coulomb_friction", "torque_offset"]])
    p.write_text(json.dumps({"selected": [], "ambiguity": [{"candidates": ["armature", "delay"], "joints": [1]}]}))
    assert question_from(str(p)) == ([], [["armature", "delay"]])
    p.write_text(json.dumps({"selected": [{"effect": "payload"}, {"effect": "armature"}]}))
    assert question_from(str(p)) == (["payload", "armature"], [])


def test_truth_file_errors(tmp_path):
    from franka_vs_gym.errors import UserError
    from franka_vs_gym.fci.truth import load_truth

    p = tmp_path / "t.json"
    for items, msg in (([{"effect": "crosstalk"}], "unsupported effect 'crosstalk'"),
                       ([{"effect": "backlash"}], "missing 'b_rad'"),
                       ([{"effect": "elastic", "K": [1e4] * 6}], "'stiffness_Nm_per_rad' must be 7"),
                       ([{"effect": "coulomb_friction", "coulomb_Nm": [1, 2]}], "'coulomb_Nm' must be 7"),
                       ([{"effect": "payload"}], "missing 'mass_kg'"),
                       ([{"effect": "delay", "delay_s": 0.5}], "delay_s must be in [0, 0.1]")):
        p.write_text(json.dumps(items))
        with pytest.raises(UserError, match=msg.replace("[", r"\[").replace("]", r"\]")):
            load_truth(p, ModelConfig())
    p.write_text(json.dumps([{"effect": "armature", "armature_kgm2": 0.1},
                             {"effect": "gravity_tilt", "tilt_deg": 3.0, "axis": [0, 1, 0]}]))
    t = load_truth(p, ModelConfig())
    assert np.allclose(t.plant.armature, 0.1)
    g = t.plant.gravity
    assert np.isclose(np.degrees(np.arccos(-g[2] / np.linalg.norm(g))), 3.0)


def test_truth_plant_differs_from_the_robots_model():
    """A tilted plant under the robot's own (vertical) gravity compensation: holding still takes a torque the
    robot's model does not predict, and the measured tau_J is the plant's gravity, not the model's."""
    from franka_vs_gym.fci import FCIServer
    from franka_vs_gym.fci.truth import Truth

    believed = ModelConfig()
    plant = believed.copy(gravity=np.array([0.0, 9.81 * np.sin(0.05), -9.81 * np.cos(0.05)]))
    with FCIServer(loopback_host(NET), lockstep=True, camera=False, verbose=False,
                   truth=Truth(plant, None, 0.0, None, "test", [])) as srv:
        q = srv.sim.get_position()
        assert np.allclose(srv.sim.model.config.gravity, believed.gravity)  # the robot believes vertical
        assert np.allclose(srv.robot.plant_gravity.gravity(q), FrankaModel(plant).gravity(q))
        for _ in range(300):  # idle: the robot holds its pose with its internal controller
            srv.robot.step(None)
        tau = srv.sim.get_force_torque()
        q = srv.sim.get_position()
    g_plant, g_model = FrankaModel(plant).gravity(q), FrankaModel(believed).gravity(q)
    assert np.abs(g_plant - g_model).max() > 0.5
    assert np.abs(tau - g_plant).max() < 0.2 * np.abs(g_plant - g_model).max()


def test_end_to_end_designed_payload_on_serve_with_hidden_truth(tmp_path):
    from franka_vs_gym.cli import main as cli_main
    from franka_vs_gym.fci import FCIServer
    from franka_vs_gym.validation.compare import as_processed
    from franka_vs_gym.validation.diagnose import diagnose
    from franka_vs_gym.validation.effects import get_effect
    from franka_vs_gym.validation.fitting import fit_effects
    from franka_vs_gym.validation.loading import load_log

    duration = 8.0
    out = tmp_path / "excite"
    assert cli_main(["excite", "--effects", "payload", "--duration", str(duration), "--time-budget", "300",
                     "--evaluations", "400", "--rest", "0.5", "-o", str(out), "--quiet", "--json"]) == 0
    truth = {"effects": [{"effect": "payload", "mass_kg": 1.3, "com_flange_m": [0.02, -0.01, 0.07]}],
             "torque_noise_Nm": 0.1, "seed": 2}
    tf = tmp_path / "truth.json"
    tf.write_text(json.dumps(truth))
    with FCIServer(loopback_host(NET + 1), lockstep=True, camera=False, verbose=False, truth=str(tf)) as srv:
        r = subprocess.run([sys.executable, str(out / "play_excitation_pylibfranka.py"), srv.host],
                           capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    rec = json.loads(r.stdout.strip().splitlines()[-1])
    assert rec["dropped"] == 0 and rec["samples"] == int(round(duration * 1000)) + 1
    log = load_log(rec["log"])
    data = as_processed(log)
    d = diagnose(data)
    assert "payload" in d.selected, d.to_dict()["selected"]
    res = fit_effects(data, ["payload"], holdout=None)
    th = get_effect("payload").coef(res.fits[0])  # m, m c (joint-7 frame), inertia
    from franka_vs_gym.validation.evaluate import FLANGE_OFFSET

    m_true, c_true = 1.3, np.array([0.02, -0.01, 0.07]) + FLANGE_OFFSET
    widths = effect_widths(data, ["payload"], ModelConfig())
    w = np.array(list(widths.values()))
    truth_vec = np.concatenate([[m_true], m_true * c_true])
    # the fit's own 95 % intervals (validation.uncertainty, HAC) hold the true mass and centre of mass
    ci = res.params_ci95["payload"]
    assert ci["mass_kg"][0] <= m_true <= ci["mass_kg"][1]
    for k, c in enumerate([0.02, -0.01, 0.07]):
        assert ci["com_flange_m"][k][0] <= c <= ci["com_flange_m"][k][1], (k, ci["com_flange_m"])
    # the truth inside the predicted 95 % interval around the fit (mass and first moments)
    assert np.all(np.abs(th[:4] - truth_vec) <= w[:4] / 2), (th[:4], truth_vec, w[:4])
    # predicted: the designed recording's intervals at least 2x narrower than a generic excitation of the same
    # duration (same noise floor, same effective sample size), median over the payload's parameters
    F_gen, _ = motion_information(generic_motion(duration), ModelConfig(), [get_effect("payload")], data.noise)
    w_gen = predicted_widths(F_gen, 100.0)
    assert np.median(w_gen / w) >= 2.0, (w_gen / w)
    # fitted: a generic excitation of the same duration (the generators' recipe, rest to rest), played the same way
    # through serve with the same hidden truth and fitted the same way: its fitted 95 % intervals (HAC) are at least
    # 2x wider than the designed recording's (median over the payload's ten parameters); and over 12 generic draws
    # the predicted gain is at least 2x (median), so the first draw played here is not a lucky one
    design = FourierMotion.from_dict(json.loads((out / "excite.json").read_text())["motion"])
    payload = [get_effect("payload")]

    def predicted(motion):
        return predicted_widths(motion_information(motion, ModelConfig(), payload, data.noise)[0], 100.0)

    w_design = predicted(design)
    gains = [np.median(predicted(generic_playable(design, seed=s)) / w_design) for s in range(1, 13)]
    assert np.median(gains) >= 2.0, np.round(gains, 2)
    generic = generic_playable(design, seed=1)
    gd = Design(generic, ["payload"], [], "D", [], [], np.zeros(0), np.zeros(0), "", np.zeros(7), 100.0, 0.0, 0)
    play = tmp_path / "play_generic_pylibfranka.py"
    play.write_text(scripts(gd, stem="generic")[play.name])
    with FCIServer(loopback_host(NET + 1), lockstep=True, camera=False, verbose=False, truth=str(tf)) as srv:
        r = subprocess.run([sys.executable, str(play), srv.host], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    rec_g = json.loads(r.stdout.strip().splitlines()[-1])
    res_g = fit_effects(as_processed(load_log(rec_g["log"])), ["payload"], holdout=None)

    def fitted_widths(ci):  # mass, m c (the regressor's first moments), inertia about the flange origin
        iu = np.triu_indices(3)
        rows = [ci["mass_kg"], *ci["com_flange_m"], *np.asarray(ci["inertia_kgm2"], dtype=float)[iu]]
        return np.array([hi - lo for lo, hi in rows])

    fitted_gain = np.median(fitted_widths(res_g.params_ci95["payload"]) / fitted_widths(ci))
    assert fitted_gain >= 2.0, (fitted_gain, gains[0])


def test_franky_script_plays_the_design(tmp_path):
    """The generated franky script, unmodified in its own process against serve, records the designed motion:
    its length, the joints within 10 mrad of the design (franky's joint impedance tracking included), and no
    torque ripple."""
    from franka_vs_gym.cli import main as cli_main
    from franka_vs_gym.fci import FCIServer
    from franka_vs_gym.validation.loading import load_log

    out = tmp_path / "excite"
    assert cli_main(["excite", "--effects", "armature", "--duration", "6", "--time-budget", "60", "--evaluations", "30",
                     "--rest", "0.5",
                     "-o", str(out), "--quiet", "--json"]) == 0
    with FCIServer(loopback_host(NET + 2), lockstep=True, camera=False, verbose=False) as srv:
        r = subprocess.run([sys.executable, str(out / "play_excitation_franky.py"), srv.host], capture_output=True,
                           text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    log = load_log(json.loads(r.stdout.strip().splitlines()[-1])["log"])
    design = np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1)
    assert abs(log.duration - design[-1, 0]) < 0.05
    q_design = np.column_stack([np.interp(log.time, design[:, 0], design[:, 1 + j]) for j in range(7)])
    assert np.abs(log.q - q_design).max() < 0.01
    assert np.ptp(log.q, axis=0).min() > 0.05  # every joint moved
    # no ripple: the torque above the 10 Hz cleaning cutoff stays at the processing's floor (a waypoint motion
    # through 50 ms waypoints put 0.9-2.6 Nm there on joints 0-3, which a 100 or 30 Hz recording folds into the band)
    from franka_vs_gym.validation.signals import clean

    assert clean(log).noise.max() < 0.1, clean(log).noise


def test_sigmoid_question_is_its_three_parameters():
    """The model's sigmoid (phi1, phi2, phi3 per joint) is designed for through the law's sensitivities: the phi1
    column is the law at height 1 (it is linear in phi1), and all 21 parameters get finite widths."""
    from franka_vs_gym.model.friction import gaz_sigmoid
    from franka_vs_gym.validation.effects import get_effect
    from franka_vs_gym.validation.excite_information import columns, motion_context

    m = _random_motion(np.random.default_rng(6), L=5)
    cfg = ModelConfig()
    ctx = motion_context(m, cfg, np.ones(7), samples=200)
    cols = columns(ctx, [get_effect("sigmoid_friction")], np.ones(7))
    fr = cfg.friction
    expect = gaz_sigmoid(ctx.data.dq, 1.0, fr.phi2, fr.phi3)
    assert np.allclose(cols.A[:, :, 0].sum(axis=1), expect[:, 0], atol=1e-6)  # joint 0's phi1 column
    F, _ = motion_information(m, cfg, [get_effect("sigmoid_friction")], np.full(7, 0.2))
    assert len(cols.names) == 21 and np.isfinite(predicted_widths(F, 100.0)).all()


def test_reference_log_and_model_file_truth(tmp_path):
    """--log: the design is compared with the log that raised the question, with that log's noise floor; a
    calibrated model file is a truth as it stands."""
    from franka_vs_gym.fci.truth import load_truth
    from franka_vs_gym.validation.compare import as_processed
    from franka_vs_gym.validation.hidden import make_hidden_effect_log

    log, _ = make_hidden_effect_log("none", seed=3, duration=6.0)
    data = as_processed(log)
    d = design_excitation(["delay"], duration=6.0, rest=0.5, time_budget=60.0, max_evaluations=30, reference=data)
    assert d.reference.startswith("the log") and np.allclose(d.noise, data.noise)
    w_ref = effect_widths(data, ["delay"], ModelConfig())["delay.delay_s"]
    assert np.isclose(d.widths_reference[0], w_ref, rtol=1e-6)
    p = tmp_path / "plant.json"
    ModelConfig(armature=np.full(7, 0.2)).save(p)
    t = load_truth(p, ModelConfig())
    assert np.allclose(t.plant.armature, 0.2) and t.payload is None
