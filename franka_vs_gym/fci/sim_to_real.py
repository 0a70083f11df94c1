"""Sim to real through libfranka's protocol: does a model calibrated from the robot's own log make a torque
controller built in simulation track better on that robot?

"The real robot" is a lock-step ``franka-vs serve --truth`` server whose plant carries effects the default model
lacks (:func:`truth_effects`: a payload in the hand, Coulomb friction beyond the Gaz law, a tilted mounting; and,
as every ``serve`` plant, the motors' effective armature, which the envs' default model does not have). Everything
the study does to it goes through unmodified libfranka clients in their own processes:

1. ``franka-vs excite`` designs an excitation; its generated pylibfranka script plays and records it on the robot;
2. ``franka-vs fit LOG --add auto`` calibrates a model from that recording (the workbench picks the effects);
3. :mod:`franka_vs_gym.fci.deploy` plays the torque controllers (computed torque, joint impedance) on
   FrankaTorqueTracking-v0's episodes with the default, the calibrated and the true plant's model, and with the
   calibrated model plus the motors' effective armature of the robot's description ("calibrated+motors": the
   motors' inertia acts before the link-side torque sensors, so no tau_J recording shows it, but the robot's
   published description states it).

Gap recovered = (err_default - err_calibrated) / (err_default - err_truth), reported where err_default >= 2
err_truth (elsewhere the model is not what limits the controller). ``scripts/sim_to_real.py`` runs it.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym.errors import UserError

CONTROLLERS = ("computed_torque", "joint_impedance")
MODELS = ("default", "calibrated", "calibrated+motors", "truth")
#: the torque agents of the study: trained on the default plant, the calibrated model, the default plant with
#: dynamics randomisation, the true plant's model
AGENT_KINDS = ("default", "calibrated", "randomized", "truth")
#: the effects the excitation is designed to identify (what a user calibrating for torque control asks about)
EXCITE_EFFECTS = "payload,gravity_tilt,coulomb_friction,armature"


def truth_effects(seed: int) -> dict[str, Any]:
    """The hidden plant of robot ``seed`` (a ``--truth`` file's object): a payload of 0.7-1.3 kg held 3-10 cm in
    front of the flange, Coulomb friction beyond the Gaz law (0.3-1.0 Nm on joints 1-4, 0.1-0.4 Nm on 5-7) and the
    mounting tilted by 1.5-2.5 deg about a random horizontal axis."""
    rng = np.random.default_rng(int(seed))
    com = [rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), rng.uniform(0.03, 0.10)]
    coulomb = np.concatenate([rng.uniform(0.3, 1.0, 4), rng.uniform(0.1, 0.4, 3)])
    a = rng.uniform(0, 2 * math.pi)
    return {"effects": [
        {"effect": "payload", "mass_kg": round(float(rng.uniform(0.7, 1.3)), 3),
         "com_flange_m": [round(float(x), 4) for x in com]},
        {"effect": "coulomb_friction", "coulomb_Nm": [round(float(x), 3) for x in coulomb]},
        {"effect": "gravity_tilt", "tilt_deg": round(float(rng.uniform(1.5, 2.5)), 3),
         "axis": [round(math.cos(a), 4), round(math.sin(a), 4), 0.0]}], "seed": int(seed)}


def true_model(truth_file: str | Path, robot: str = "fer") -> Any:
    """The true plant's model (a ModelConfig) of a ``--truth`` file served by ``franka-vs serve``: the effects it
    lists, the payload held (as a declared payload of the model) and the motors' effective armature every served
    plant carries (``RobotDescription.rotor_inertia``)."""
    from franka_vs_gym.fci.truth import load_truth
    from franka_vs_gym.model.config import resolve_config

    base = resolve_config(None, robot)
    t = load_truth(truth_file, base)
    cfg = t.plant.copy(payload=t.payload)
    return cfg.copy(armature=cfg.armature + np.asarray(base.robot.rotor_inertia, dtype=np.float64))


def with_motors(model_file: str | Path, robot: str = "fer") -> Any:
    """The model of ``model_file`` plus the motors' effective armature of the robot's description
    (``RobotDescription.rotor_inertia``) on top of the armature it has."""
    from franka_vs_gym.model.config import resolve_config

    cfg = resolve_config(str(model_file), robot)
    return cfg.copy(armature=cfg.armature + np.asarray(cfg.robot.rotor_inertia, dtype=np.float64))


def gap_recovered(err_default: float, err_calibrated: float, err_truth: float) -> float | None:
    """(err_default - err_calibrated) / (err_default - err_truth), or None where err_default < 2 err_truth."""
    if not err_default >= 2 * err_truth:
        return None
    return (err_default - err_calibrated) / (err_default - err_truth)


def _env() -> dict[str, str]:
    """The environment of the client processes: this package importable (the scripts import it), one thread."""
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        env.setdefault(k, "1")
    return env


def _die_with_parent() -> None:
    """In a child process before exec (Linux): ask the kernel to send it SIGTERM when the study's process dies,
    whatever kills it (the study also ends its children itself on SIGTERM / SIGINT: stop_on_signals)."""
    if sys.platform.startswith("linux"):
        import ctypes

        try:
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG = 1
        except OSError:
            pass


def stop_on_signals() -> None:
    """SIGTERM (and SIGINT, as usual) end the study by an exception, so that every context (a truth server, a
    client process of ``subprocess.run``) ends its children on the way out."""
    def _stop(signum: int, frame: Any) -> None:
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, _stop)


def _run(args: list[str], what: str, timeout: float) -> str:
    r = subprocess.run(args, capture_output=True, text=True, timeout=timeout, env=_env(),
                       preexec_fn=_die_with_parent)
    if r.returncode != 0:
        tail = (r.stderr or r.stdout).strip().splitlines()[-3:]
        raise RuntimeError(f"{what} failed (exit {r.returncode}): {' | '.join(tail)}")
    return r.stdout


class TruthServer:
    """``franka-vs serve --lockstep --truth FILE`` in its own process on ``host`` (a context manager)."""

    def __init__(self, host: str, truth: str | Path, robot: str = "fer") -> None:
        self.host, self.truth, self.robot = host, str(truth), robot
        self.proc: subprocess.Popen | None = None

    def __enter__(self) -> TruthServer:
        self.proc = subprocess.Popen([sys.executable, "-m", "franka_vs_gym.cli", "serve", "--lockstep", "--host",
                                      self.host, "--truth", self.truth, "--robot", self.robot, "--no-camera"],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(),
                                     preexec_fn=_die_with_parent)
        try:
            line = self.proc.stdout.readline() if self.proc.stdout else ""
            if "ready at" not in line:
                err = self.proc.stderr.read() if self.proc.stderr else ""
                raise RuntimeError(f"franka-vs serve did not start on {self.host}: {(line + err).strip()[-300:]}")
        except BaseException:  # (also a signal's exit while waiting: the server must not outlive the study)
            self.proc.kill()
            self.proc.wait()
            raise
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.proc is not None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def design_excitation(out: Path, duration: float, evaluations: int = 200, time_budget: float = 120.0,
                      fraction: float = 0.5) -> Path:
    """``franka-vs excite`` for :data:`EXCITE_EFFECTS` (``fraction``: of the robot's velocity, acceleration and
    jerk limits the motion may use); returns the generated pylibfranka script."""
    _run([sys.executable, "-m", "franka_vs_gym.cli", "excite", "--effects", EXCITE_EFFECTS, "--duration",
          str(duration), "--evaluations", str(int(evaluations)), "--time-budget", str(time_budget), "--rest", "0.5",
          "--fraction", str(fraction), "-o", str(out), "--quiet"], "franka-vs excite", timeout=time_budget + 300)
    return out / "play_excitation_pylibfranka.py"


def record(script: Path, host: str, copy_to: Path) -> Path:
    """Play the excitation script (pylibfranka, its own process) on the robot at ``host``; the recording moved to
    ``copy_to`` (+ its .json sidecar)."""
    for attempt in range(2):  # (once more if the robot's state stopped arriving: a starved machine, not the motion)
        try:
            rec = json.loads(_run([sys.executable, str(script), host], "the excitation recording",
                                  timeout=900).strip().splitlines()[-1])
            break
        except RuntimeError as e:
            if attempt or "NetworkException" not in str(e):
                raise
            time.sleep(1.0)
    src = Path(rec["log"])
    os.replace(src, copy_to)
    side = Path(str(src) + ".json")
    if side.exists():
        os.replace(side, Path(str(copy_to) + ".json"))
    return copy_to


def calibrate(log: Path, out: Path, robot: str = "fer") -> dict[str, Any]:
    """``franka-vs fit LOG --add auto -o OUT``; its JSON summary."""
    s = _run([sys.executable, "-m", "franka_vs_gym.cli", "fit", str(log), "--add", "auto", "--robot", robot, "-o",
              str(out), "--quiet", "--json"], "franka-vs fit", timeout=1800)
    return json.loads(s.strip().splitlines()[-1])


def deploy(host: str, policy: str, model: str | None, seeds: list[int], robot: str = "fer") -> dict[str, Any]:
    """:mod:`franka_vs_gym.fci.deploy` in its own process (pylibfranka): the episodes' results."""
    args = [sys.executable, "-m", "franka_vs_gym.fci.deploy", host, "--policy", policy, "--robot", robot, "--seeds",
            ",".join(str(s) for s in seeds)]
    if model is not None:
        args += ["--model", str(model)]
    return json.loads(_run(args, f"the {policy} run", timeout=120 + 60 * len(seeds)).strip().splitlines()[-1])


def run_robot(seed: int, out: Path, host: str, excitation: Path, episode_seeds: list[int],
              controllers: tuple[str, ...] = CONTROLLERS, robot: str = "fer",
              say: Callable[[str], None] = lambda s: None,
              agents: Callable[[dict[str, str | None]], dict[str, list[str]]] | None = None) -> dict[str, Any]:
    """The whole study on robot ``seed``: truth file, server, recording, calibration, the controllers' runs.
    Files go to ``out`` (``truth.json``, ``true_model.json``, ``excitation.csv``, ``calibrated.json``).

    ``agents``: called after the calibration with the models (``default``: None, ``calibrated``, ``truth``: model
    files), returns the torque agents to play on this robot, ``{kind: [agent zip, ...]}`` (kinds
    :data:`AGENT_KINDS`: trained on the default plant, on the calibrated model, on the default with dynamics
    randomisation, on the true plant's model; one zip per training seed); each is played through pylibfranka with
    the plant model of its training (its sidecar's) and the results go to ``runs["agent/<kind>"]``, with the agent's
    gap recovered (mean over the seeds of each kind)."""
    out.mkdir(parents=True, exist_ok=True)
    truth_file = out / "truth.json"
    truth_file.write_text(json.dumps(truth_effects(seed), indent=1))
    true_file = out / "true_model.json"
    true_model(truth_file, robot).save(true_file, overwrite=True)
    models = {"default": None, "calibrated": str(out / "calibrated.json"),
              "calibrated+motors": str(out / "calibrated_motors.json"), "truth": str(true_file)}
    result: dict[str, Any] = {"seed": seed, "truth": truth_effects(seed), "runs": {}}
    with TruthServer(host, truth_file, robot):
        t = time.perf_counter()
        say(f"robot {seed}: recording the excitation through pylibfranka")
        log = record(excitation, host, out / "excitation.csv")
        say(f"robot {seed}: recorded in {time.perf_counter() - t:.0f} s; calibrating (franka-vs fit --add auto)")
        t = time.perf_counter()
        fit = calibrate(log, out / "calibrated.json", robot)
        result["fit"] = {"effects": fit.get("effects"), "params": fit.get("params"), "seconds":
                         round(time.perf_counter() - t, 1)}
        say(f"robot {seed}: fitted {', '.join(fit.get('effects') or []) or 'nothing'} "
            f"in {time.perf_counter() - t:.0f} s")
        with_motors(out / "calibrated.json", robot).save(out / "calibrated_motors.json", overwrite=True)
        for c in controllers:
            for m in MODELS:
                t = time.perf_counter()
                r = deploy(host, c, models[m], episode_seeds, robot)
                eps = r["episodes"]
                err = float(np.mean([e["rms_error"] for e in eps]))
                result["runs"][f"{c}/{m}"] = {"rms_error": err, "success": sum(e["success"] for e in eps),
                                              "failures": [e["failure"] for e in eps if e["failure"]],
                                              "episodes": eps}
                say(f"robot {seed}: {c} with the {m} model: mean rms error {err:.5f} rad over {len(eps)} episodes "
                    f"({time.perf_counter() - t:.0f} s)")
        if agents is not None:
            result["runs"].update(_play_agents(agents(models), host, episode_seeds, robot, seed, say))
        for c in controllers:
            e = {m: result["runs"][f"{c}/{m}"]["rms_error"] for m in MODELS}
            result["runs"][f"{c}/gap_recovered"] = gap_recovered(e["default"], e["calibrated"], e["truth"])
            result["runs"][f"{c}/gap_recovered_motors"] = gap_recovered(e["default"], e["calibrated+motors"],
                                                                        e["truth"])
    return result


def _play_agents(kinds: dict[str, list[str]], host: str, episode_seeds: list[int], robot: str, seed: int,
                 say: Callable[[str], None]) -> dict[str, Any]:
    """Each agent of each kind through :func:`deploy` (its own plant model); per kind the per-seed mean RMS errors,
    their mean, the successes, and the gaps recovered."""
    runs: dict[str, Any] = {}
    for kind, zips in kinds.items():
        per_seed = []
        for z in zips:
            t = time.perf_counter()
            eps = deploy(host, str(z), None, episode_seeds, robot)["episodes"]
            per_seed.append({"agent": str(z), "rms_error": float(np.mean([e["rms_error"] for e in eps])),
                             "success": sum(e["success"] for e in eps),
                             "failures": [e["failure"] for e in eps if e["failure"]], "episodes": eps})
            say(f"robot {seed}: agent {kind} ({Path(z).stem}): mean rms error {per_seed[-1]['rms_error']:.5f} rad, "
                f"{per_seed[-1]['success']} of {len(eps)} successes ({time.perf_counter() - t:.0f} s)")
        errs = [p["rms_error"] for p in per_seed]
        runs[f"agent/{kind}"] = {"rms_error": float(np.mean(errs)), "rms_error_per_seed": errs,
                                 "success": sum(p["success"] for p in per_seed),
                                 "episodes_total": sum(len(p["episodes"]) for p in per_seed), "seeds": per_seed}
    e = {k: runs[f"agent/{k}"]["rms_error"] for k in kinds}
    if {"default", "truth"} <= set(e):
        for k in ("calibrated", "randomized"):
            if k in e:
                runs[f"agent/gap_recovered_{k}"] = gap_recovered(e["default"], e[k], e["truth"])
    return runs


def check_host(host: str) -> None:
    """A loopback address to serve on (the servers bind 127.0.0.x only)."""
    if not host.startswith("127."):
        raise UserError(f"--host {host}: the study's servers bind loopback addresses (127.x.y.z) only")


__all__ = ["AGENT_KINDS", "CONTROLLERS", "EXCITE_EFFECTS", "MODELS", "TruthServer", "calibrate", "check_host", "deploy",
           "design_excitation", "gap_recovered", "record", "run_robot", "stop_on_signals", "true_model",
           "truth_effects", "with_motors"]
