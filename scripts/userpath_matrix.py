"""The user's path on every real recording in ../shared/data, at every rate and in every form.

For each recording (the Gaz et al. 2019 FER log, the two FR3 teleoperation runs, the 30 Hz ROS 1 FER bag and its two
halves by time), each rate (its own, and copies keeping every 10th and every 33rd row: about 100 Hz and 30 Hz) and
each form (CSV with a sidecar naming the robot and the tool, CSV without a sidecar, the bag itself), from the
shipped model and from ``--rigid-body``, this runs what a user runs, each command in its own process::

    franka-vs compare LOG [--robot R]
    franka-vs diagnose LOG [--robot R]
    franka-vs fit LOG [--robot R] --add auto -o model.json
    franka-vs compare LOG [--robot R] --model model.json --report DIR

and counts how many end with a calibrated model, how many replays stop (and where, why), and every refusal with its
message. The copies are written to a temporary folder and deleted; nothing of the recordings is kept. The locked
part of the evaluation (the FR3 run 162853, the bag's second half) is run like the rest: nothing here is fitted or
tuned on its outcome.

    python scripts/userpath_matrix.py -o userpath.json [--data ../shared/data] [--only gaz,fr3,bag]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CLI = "import sys; from franka_vs_gym.cli import main; sys.exit(main(sys.argv[1:]))"


def run(args: list[str], timeout: float = 900) -> tuple[int, str, str]:
    r = subprocess.run([sys.executable, "-W", "ignore", "-c", CLI, *args], capture_output=True, text=True,
                       timeout=timeout)
    return r.returncode, r.stdout, r.stderr


def error_line(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if "error" in ln or "Traceback" in ln]
    return (lines[-1] if lines else err.strip().splitlines()[-1] if err.strip() else "")[:400]


def read_fr3(path: Path):
    """An FR3 teleoperation CSV (columns t, q0..q6, dq0..dq6, tau_J0..tau_J6) read with numpy."""
    from franka_vs_gym.validation.logs import MeasurementLog

    a = np.loadtxt(path, delimiter=",", skiprows=1)
    return MeasurementLog(a[:, 0], a[:, 1:8], a[:, 8:15], a[:, 15:22], tool="franka_hand")


def logs(data: Path, tmp: Path, only: set[str]) -> list[dict]:
    """The recordings as (name, path, robot flag, locked) in every form and rate, written into ``tmp``."""
    from franka_vs_gym.validation.loading import load_log
    from franka_vs_gym.validation.logs import MeasurementLog, save_log

    out = []

    def forms(name: str, log: MeasurementLog, robot: str, tool, locked: bool, rates=((1, "own"), (10, "1/10"),
                                                                                      (33, "1/33"))):
        for k, rate in rates:
            idx = np.arange(0, log.n, k)
            for side in (True, False):
                sub = MeasurementLog(log.time[idx], log.q[idx], log.dq[idx], log.tau_J[idx], tool=tool,
                                     extra={"robot": robot} if side else {})
                p = save_log(sub, tmp / f"{name}_{k}_{'side' if side else 'bare'}.csv")
                if not side:
                    (tmp / f"{p.name}.json").unlink()  # no sidecar: the robot and the tool are not declared
                out.append({"recording": name, "rate": rate, "form": "csv+sidecar" if side else "csv",
                            "path": str(p), "robot_flag": [] if side else ["--robot", robot], "locked": locked})

    if "gaz" in only and (data / "gaz2019_traj1").is_dir():
        forms("gaz2019", load_log(data / "gaz2019_traj1"), "fer", None, False)
    fr3 = data / "fr3_teleop_follower"
    if "fr3" in only and fr3.is_dir():
        for run_id, locked in (("162545", False), ("162853", True)):
            forms(f"fr3_{run_id}", read_fr3(fr3 / f"run_{run_id}.csv"), "fr3", "franka_hand", locked)
    bag = data / "fer_joint_states_ros1" / "joint_states.bag"
    if "bag" in only and bag.is_file():
        out.append({"recording": "ros1_bag", "rate": "own", "form": "bag", "path": str(bag), "robot_flag": [],
                    "locked": True})
        log = load_log(bag)
        half = log.time[0] + 0.5 * (log.time[-1] - log.time[0])
        for part, m, locked in (("first", log.time <= half, False), ("second", log.time > half, True)):
            sub = MeasurementLog(log.time[m] - log.time[m][0], log.q[m], log.dq[m], log.tau_J[m], tool="franka_hand")
            forms(f"ros1_bag_{part}_half", sub, "fer", "franka_hand", locked, rates=((1, "own"),))
    return out


def user_path(case: dict, rigid: bool, tmp: Path) -> dict:
    p, rf = case["path"], case["robot_flag"]
    rb = ["--rigid-body"] if rigid else []
    tag = Path(p).stem + ("_rb" if rigid else "")
    res: dict = {k: case[k] for k in ("recording", "rate", "form", "locked")}
    res["start"] = "rigid_body" if rigid else "shipped"
    t0 = time.time()
    rc, out, err = run(["compare", p, *rf, *rb, "--json", "--quiet"])
    if rc != 0:
        res["compare"] = {"refused": error_line(err)}
    else:
        c = json.loads(out)
        rp = c.get("replay") or {}
        res["compare"] = {"rmse_tau_total": c["rmse_tau_total"], "replay_stop": rp.get("stop"),
                          "replay_fallback": rp.get("fallback_from"), "replay_rmse_tau_total": rp.get("rmse_tau_total")}
    rc, out, err = run(["diagnose", p, *rf, *rb, "--json", "--quiet"])
    if rc != 0:
        res["diagnose"] = {"refused": error_line(err)}
    else:
        d = json.loads(out)
        res["diagnose"] = {"verdict": d["verdict"], "selected": [s["effect"] for s in d["selected"]],
                           "explained": d["explained"], "notes": d["notes"]}
    model = tmp / f"{tag}.model.json"
    rc, out, err = run(["fit", p, *rf, *rb, "--add", "auto", "-o", str(model), "--json", "--quiet", "--force"])
    if rc != 0:
        res["fit"] = {"refused": error_line(err)}
    else:
        f = json.loads(out)
        res["fit"] = {"effects": f["effects"], "rmse_before": f["rmse_tau_total_before"],
                      "rmse_after": f["rmse_tau_total_after"], "notes": f["notes"],
                      "holdout_total": None if not f.get("holdout") else
                      [f["holdout"]["rmse_tau_total_before"], f["holdout"]["rmse_tau_total_after"]]}
        rc, out, err = run(["compare", p, *rf, "--model", str(model), "--report", str(tmp / f"{tag}.report"),
                            "--json", "--quiet", "--force"])
        if rc != 0:
            res["compare_model"] = {"refused": error_line(err)}
        else:
            c = json.loads(out)
            rp = c.get("replay") or {}
            res["compare_model"] = {"rmse_tau_total": c["rmse_tau_total"], "replay_stop": rp.get("stop"),
                                    "replay_fallback": rp.get("fallback_from")}
    res["seconds"] = round(time.time() - t0, 1)
    return res


def summary(rows: list[dict]) -> str:
    n = len(rows)
    calibrated = sum("effects" in r.get("fit", {}) for r in rows)
    stops = [r for r in rows for k in ("compare", "compare_model")
             if r.get(k, {}).get("replay_stop") or r.get(k, {}).get("replay_fallback")]
    refusals: dict[str, int] = {}
    for r in rows:
        for k in ("compare", "diagnose", "fit", "compare_model"):
            msg = r.get(k, {}).get("refused")
            if msg:
                refusals[f"{k}: {msg}"] = refusals.get(f"{k}: {msg}", 0) + 1
    lines = [f"{n} runs of the user's path; {calibrated} end with a calibrated model; {len(stops)} replays stopped"]
    for r in stops:
        lines.append(f"  replay stop: {r['recording']} {r['rate']} {r['form']} {r['start']}")
    for msg, k in sorted(refusals.items()):
        lines.append(f"  refused {k}x: {msg}")
    lines.append("recording             rate  form         start       compare  diagnose (verdict)        fit")
    for r in rows:
        c = r.get("compare", {})
        d = r.get("diagnose", {})
        f = r.get("fit", {})
        lines.append(f"{r['recording']:<21s} {r['rate']:>5s} {r['form']:<12s} {r['start']:<11s} "
                     f"{'refused' if 'refused' in c else 'stop' if c.get('replay_stop') else 'ok':<8s} "
                     f"{d.get('verdict', 'refused'):<25s} "
                     + ("refused" if "refused" in f else f"{f['rmse_before']:.3f}->{f['rmse_after']:.3f} Nm "
                        f"{'+'.join(f['effects']) or 'nothing'}"))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--output", required=True, help="JSON file to write (refused if it exists)")
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    ap.add_argument("--only", default="gaz,fr3,bag", help="recordings: gaz, fr3, bag (comma separated)")
    ap.add_argument("--rigid-body", choices=("both", "no", "only"), default="both")
    a = ap.parse_args(argv)
    out = Path(a.output)
    if out.exists():
        ap.error(f"{out} exists; choose another name")
    data = Path(a.data)
    if not data.is_dir():
        ap.error(f"{data}: no such folder (the real recordings)")
    starts = {"both": (False, True), "no": (False,), "only": (True,)}[a.rigid_body]
    rows = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        cases = logs(data, tmp, set(a.only.split(",")))
        total = len(cases) * len(starts)
        for case in cases:
            for rigid in starts:
                r = user_path(case, rigid, tmp)
                rows.append(r)
                print(f"[{len(rows)}/{total}] {r['recording']} {r['rate']} {r['form']} {r['start']}: "
                      f"fit {'refused' if 'refused' in r.get('fit', {}) else 'ok'} ({r['seconds']} s)",
                      file=sys.stderr, flush=True)
                out.write_text(json.dumps(rows, indent=1))
    print(summary(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
