"""What the report and the terminal show, without a browser: the verdict with its fitted values first, progress on
one updating line, report.html's content and size, the phase view of a periodic finding, the display decimation."""

from __future__ import annotations

import json
import re
import types
from pathlib import Path

import numpy as np
import pytest

from franka_vs_gym.cli import main as cli
from franka_vs_gym.validation.hidden import make_hidden_effect_log
from franka_vs_gym.validation.logs import save_log
from franka_vs_gym.validation.report.content import (
    binned_mean,
    correlation_lines,
    envelope,
    finding_views,
    unit_of,
    value_text,
)
from franka_vs_gym.validation.structure import Finding, Unexplained


@pytest.fixture(scope="module")
def tilt_log(tmp_path_factory) -> Path:
    log, _ = make_hidden_effect_log("gravity_tilt", 41, duration=8.0, magnitude=1.5)
    return save_log(log, tmp_path_factory.mktemp("views") / "tilt.csv")


def test_diagnose_prints_verdict_with_values_first_and_one_progress_line(tilt_log, tmp_path, capsys):
    rep = tmp_path / "rep"
    assert cli(["diagnose", str(tilt_log), "--report", str(rep)]) == 0
    out, err = capsys.readouterr()
    lines = out.splitlines()
    assert lines[0] == "verdict: gravity_tilt"
    # the fitted value on the next line, with its unit: a tilt of 1.5 x 4 deg (x [0.7, 1.3])
    m = re.search(r"tilt ([0-9.]+) \[([0-9.]+), ([0-9.]+)\] deg", lines[1])  # the value and its 95 % interval
    assert lines[1].lstrip().startswith("gravity_tilt") and m and 4.0 < float(m.group(1)) < 10.0
    assert float(m.group(2)) <= float(m.group(1)) <= float(m.group(3))
    assert "m/s^2" in lines[1]
    assert lines[-1].startswith("next: franka-vs fit ") and "--add gravity_tilt" in lines[-1]
    assert "each effect alone" not in out  # the ranking is a detail (--verbose)
    # progress: one updating line (carriage returns), no stage per line
    assert "[franka-vs]" in err
    assert err.count("\n") <= 1, err
    # --verbose: one line per stage and the ranking
    assert cli(["diagnose", str(tilt_log), "--verbose"]) == 0
    out_v, err_v = capsys.readouterr()
    assert "each effect alone" in out_v and err_v.count("\n[franka-vs]") + err_v.startswith("[franka-vs]") > 10

    # report.html: self-contained, small, says the verdict with units, the ranking's status and the next command
    html = (rep / "report.html").read_text()
    assert (rep / "report.html").stat().st_size < 5e6
    assert not re.findall(r'<(?:script|link)[^>]+(?:src|href)="https?://', html)
    assert "Verdict: gravity_tilt" in html and "m/s^2" in html and "deg" in html
    assert "franka-vs fit" in html and "Bokeh" in html
    assert "True" not in re.sub(r"<script.*?</script>", "", html, flags=re.S)
    md = (rep / "report.md").read_text()
    assert "| True |" not in md and "| False |" not in md  # statuses in words, next to the reasons
    assert "| gravity_tilt | tilt |" in md and "deg" in md


def test_fit_prints_one_line_per_effect(tilt_log, tmp_path, capsys):
    out_file = tmp_path / "cal.json"
    assert cli(["fit", str(tilt_log), "--add", "gravity_tilt", "-o", str(out_file)]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[0].startswith("fitted: gravity_tilt; total torque RMSE")
    assert lines[1].lstrip().startswith("gravity_tilt") and "m/s^2" in lines[1]
    # no parameter spread one number per line: every line with a number list holds the whole list
    assert not any(re.fullmatch(r"\s*-?[0-9.]+,?", x) for x in lines)
    assert lines[-1].startswith("next: franka-vs diagnose")


def test_periodic_finding_is_shown_against_its_phase():
    """A residual periodic in q with period P, seen against the phase of P, is one clean cycle (its binned mean
    recovers the sine), whatever the range of q."""
    rng = np.random.default_rng(0)
    period = 0.898
    q = rng.uniform(-2.5, 2.5, 20000)
    r = 0.4 * np.sin(2 * np.pi * q / period + 0.3) + 0.05 * rng.standard_normal(q.size)
    u = Unexplained(False, np.ones(7), np.full(7, 0.05),
                    [Finding(2, "periodic_q", 0.28, 100.0, f"period {period:.3g} rad (7 per turn)")], [],
                    {2: ("periodic_q", q, r, np.array([0.05]))})
    (v,) = finding_views(types.SimpleNamespace(unexplained=u))
    assert v.joint == 2 and "phase" in v.xlabel and v.x.min() >= 0 and v.x.max() <= 360
    xm, rm = binned_mean(v.x, v.r, bins=36)
    expect = 0.4 * np.sin(np.radians(xm) + 0.3)
    assert np.nanmax(np.abs(rm - expect)) < 0.06  # the bins' width smears a 0.4 Nm sine by at most ~0.01 Nm


def test_envelope_keeps_peaks_and_order():
    t = np.linspace(0, 30, 30000)
    y = 0.01 * np.sin(t)
    y[12345] = 5.0  # a one-sample spike
    y[23456] = -3.0
    tt, yy = envelope(t, y, 1600)
    assert len(tt) <= 1600 and np.all(np.diff(tt) >= 0)
    assert yy.max() == 5.0 and yy.min() == -3.0


def test_units_from_parameter_names():
    assert unit_of("viscous_Nms_per_rad") == ("viscous", "Nm s/rad")
    assert unit_of("coulomb_vel_rad_per_s") == ("coulomb_vel", "rad/s")
    assert unit_of("delta_gravity_m_per_s2") == ("delta_gravity", "m/s^2")
    from franka_vs_gym.validation.report.content import ParamRow

    row = ParamRow("viscous_friction", "viscous", "Nm s/rad", [0.1, 0.0, 0.3, None, 0, 0, 0],
                   [[0.09, 0.11], None, [0.2, 0.4], None, None, None, None])
    assert value_text(row) == "j0 0.1 [0.09, 0.11], j2 0.3 [0.2, 0.4] Nm s/rad"
    assert value_text(ParamRow("gravity_tilt", "tilt", "deg", 0.31, [0.25, 0.37])) == "0.31 [0.25, 0.37] deg"
    assert json.dumps(value_text(ParamRow("payload", "mass", "kg", 1.2)))  # plain value, no interval


def test_excite_report_shows_what_excite_computed(tmp_path, capsys):
    """``excite --report``: every parameter's predicted widths in report.md are excite.json's (read, not computed
    again), the motion drawn is trajectory.csv's, the commands name the written scripts, and the PNGs exist."""
    from franka_vs_gym.validation.report.excite import view

    out, rep = tmp_path / "next", tmp_path / "rep"
    assert cli(["excite", "--effects", "armature", "--separate", "coulomb_friction,torque_offset", "--duration", "8",
                "--rest", "0.5", "--evaluations", "20", "-o", str(out), "--report", str(rep), "--quiet"]) == 0
    assert f"report: {rep / 'report.html'}" in capsys.readouterr().out
    design = json.loads((out / "excite.json").read_text())
    md = (rep / "report.md").read_text()
    widths = design["predicted_ci95_width"]
    assert len(widths) == 21  # armature, coulomb_friction, torque_offset: 7 joints each
    for name, w in widths.items():
        m = re.search(rf"^\| {re.escape(name)} \| ([^|]+) \| ([^|]+) \| ([^|]+) \|", md, flags=re.M)
        assert m, name
        for cell, value in zip(m.groups()[1:], (w["designed"], w["reference"]), strict=True):
            assert (cell.strip() == "not identifiable") if value is None else \
                abs(float(cell) - value) <= 5e-3 * abs(value), (name, cell, value)
    assert "| armature[0] | kg m^2 |" in md and "| coulomb_friction[3] | Nm |" in md
    assert "coulomb_friction and torque_offset" in md
    for s in design["summary"]:
        assert f"{s['median_width_ratio_reference_over_designed']:.3g}x narrower" in md
    assert f"python {out}/play_excitation_pylibfranka.py 127.0.0.1" in md and (out / "play_excitation_pylibfranka.py"
                                                                               ).exists()
    assert "franka-vs serve --lockstep" in md and "--add armature,coulomb_friction,torque_offset" in md
    assert (rep / "excitation_limits.png").stat().st_size > 10_000 and (rep / "predicted_widths.png").exists()
    html = (rep / "report.html").read_text()
    assert (rep / "report.html").stat().st_size < 5e6 and "Bokeh" in html
    # the view reads trajectory.csv's rows: peak velocity over the robot's limit is excite's own figure
    table = np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1)
    v = view(design, table, out)
    peak = np.abs(v.signal(1)).max(axis=0) / v.robot["dq_max_rad_per_s"]
    assert np.allclose(peak, design["limits"]["peak_dq_over_limit"], atol=2e-3)
    assert (peak <= design["limits"]["fraction_of_limits"] + 1e-6).all()
    # a second run into the same report folder is refused (nothing the user wrote is overwritten)
    assert cli(["excite", "--effects", "armature", "--duration", "8", "--rest", "0.5", "--evaluations", "5", "-o",
                str(tmp_path / "next2"), "--report", str(rep), "--quiet"]) != 0
    assert "exists" in capsys.readouterr().err
    assert not (tmp_path / "next2").exists()


def test_design_parameter_names_and_units():
    from franka_vs_gym.validation.report.excite import parameter

    assert parameter("viscous_friction[3]") == ("viscous_friction", "F_v", 3, "Nm s/rad")
    assert parameter("asymmetric_friction.c1[0]") == ("asymmetric_friction", "F_minus", 0, "Nm")
    assert parameter("payload.m_kg") == ("payload", "m", None, "kg")
    assert parameter("payload.m*c_x_kgm") == ("payload", "m*c_x", None, "kg m")
    assert parameter("payload.Ixy_kgm2") == ("payload", "Ixy", None, "kg m^2")
    assert parameter("sigmoid_friction.phi2_s_per_rad[5]") == ("sigmoid_friction", "phi2", 5, "s/rad")
    assert parameter("gravity_tilt.dg_x") == ("gravity_tilt", "dg_x", None, "m/s^2")
    assert parameter("delay.delay_s") == ("delay", "delay", None, "s")


def test_alongside_runs_the_work_and_raises_its_error_here(tmp_path):
    """The report's PNGs are written by a forked child where a second CPU is free: the work is done (in a child
    when it can be), and a failure there is raised in the caller as if it had run there."""
    import os
    import threading

    from franka_vs_gym.validation.cli_common import alongside

    marker = tmp_path / "pid"
    alongside(lambda: marker.write_text(str(os.getpid())))()
    assert marker.exists()
    if len(os.sched_getaffinity(0)) >= 2 and threading.active_count() == 1:
        assert int(marker.read_text()) != os.getpid()  # it ran in a child

    def bad():
        raise ValueError("figure failed")

    with pytest.raises(ValueError, match="figure failed"):
        alongside(bad)()


def test_excite_report_refuses_a_design_without_limits(tmp_path):
    from franka_vs_gym.errors import UserError
    from franka_vs_gym.validation.report.excite import excite_report

    with pytest.raises(UserError, match="robot_limits"):
        excite_report({"limits": {"fraction_of_limits": 0.5}}, np.zeros((10, 22)), tmp_path / "r", tmp_path)
    with pytest.raises(UserError, match="22 columns"):
        excite_report({"limits": {"robot_limits": {"q_min_rad": [0] * 7}}}, np.zeros((10, 5)), tmp_path / "r",
                      tmp_path)
    assert not (tmp_path / "r").exists()


def test_a_correlated_pair_between_two_effects_is_said_once():
    """The payload lists (mass, gravity z) and the tilt (gravity z, mass): one line, the strongest first, with the
    count of the rest beyond the top ones."""
    pairs = [{"a": "payload mass", "b": "gravity z", "r": 0.927}, {"a": "gravity z", "b": "payload mass", "r": 0.927},
             {"a": "offset j0", "b": "offset j3", "r": -0.95}]
    lines = correlation_lines(pairs)
    assert lines == ["  correlated: offset j0 and offset j3 (r = -0.95)",
                     "  correlated: payload mass and gravity z (r = 0.927)"]
    many = [{"a": f"p{i}", "b": f"q{i}", "r": 0.91 + i / 1000} for i in range(7)]
    more = "  correlated: 2 more pairs with abs(r) > 0.9 (--verbose or --json)"
    assert correlation_lines(many + many[::-1])[-1] == more
