#!/usr/bin/env python
"""Write the env x robot x policy table of docs/envs.md from the shipped agents' sidecars and the scripted policies'
evaluation file.

    python scripts/envs_table.py              # rewrite the table in docs/envs.md (between its markers)
    python scripts/envs_table.py --check      # exit 1 when docs/envs.md's table is out of date
    python scripts/envs_table.py --scripted   # evaluate the scripted policies again (100 episodes per env and
                                              # robot, a few minutes) into docs/envs_scripted.json, then the table
    python scripts/envs_table.py --figure docs/images/envs_agents.png   # also draw the agents' training curves

Sources, nothing else: every agent sidecar ``franka_vs_gym/policies/agents/*.json`` (its ``env_id``, ``robot``
(absent: the FER), ``evaluation``, ``evaluation_other_robot``, ``timesteps``, ``train_time_s``, ``train_cpu_s``)
and ``docs/envs_scripted.json`` (what ``--scripted`` measured with ``franka_vs_gym.evaluate``: the scripted
controller of each env on each robot). One row per env, robot and policy: the scripted controller; each agent
trained on that robot (its own evaluation, and in the last column the same agent on the other robot); and, where no
agent was trained on that robot, the other robot's agent evaluated there. ``tests/test_envs_agents.py`` checks that
docs/envs.md holds exactly what this script writes.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
AGENTS = ROOT / "franka_vs_gym" / "policies" / "agents"
SCRIPTED = ROOT / "docs" / "envs_scripted.json"
DOC = ROOT / "docs" / "envs.md"
BEGIN = "<!-- envs-table: begin (written by scripts/envs_table.py from the agents' sidecars and " \
        "docs/envs_scripted.json; do not edit) -->"
END = "<!-- envs-table: end -->"
ENVS = ("FrankaIBVS-v0", "FrankaPBVS-v0", "FrankaTorqueTracking-v0", "FrankaVisualTorque-v0",
        "FrankaIBVSEyeToHand-v0", "FrankaPBVSEyeToHand-v0")
ROBOTS = ("fer", "fr3")
#: the scripted controller of each env (the package's policies; FrankaVisualTorque-v0 has none)
SCRIPTED_POLICIES = {"FrankaIBVS-v0": "IBVSPolicy", "FrankaPBVS-v0": "PBVSPolicy",
                     "FrankaTorqueTracking-v0": "ComputedTorquePolicy",
                     "FrankaIBVSEyeToHand-v0": "IBVSEyeToHandPolicy", "FrankaPBVSEyeToHand-v0": "PBVSEyeToHandPolicy"}
EPISODES, SEED = 100, 20_000


def _pct(r: dict[str, Any] | None) -> str:
    if not r:
        return "-"
    n = r.get("n_episodes")
    s = r["success_rate"]
    seed = r.get("seed")
    where = f" ({seed}-{seed + n - 1})" if n and seed is not None else ""
    return f"{s:.2f} of {n}{where}" if n else f"{s:.2f}"


def _ttc(r: dict[str, Any] | None, env: str) -> str:
    """The mean time to converge; the tracking task is judged over its whole episode: its median final error."""
    if env == "FrankaTorqueTracking-v0":
        v = (r or {}).get("median_final_error")
        return "-" if v is None else f"(tracking) median final error {v:.4f} rad"
    v = (r or {}).get("mean_time_to_converge")
    return "-" if v is None else f"{v:.2f} s"


def _n(x: int) -> str:
    return f"{x:,}".replace(",", " ")


def _training(m: dict[str, Any]) -> str:
    tr = m.get("training")
    if isinstance(tr, dict) and "method" in tr:  # the DAgger student's sidecar (baselines/train_pixels.py)
        return (f"{tr['method'].split(' ')[0]}, {_n(tr['saved_samples'])} labelled states, "
                f"{tr['wall_s'] / 60:.1f} min wall / {tr['cpu_s'] / 60:.1f} min CPU")
    steps = m.get("timesteps")
    wall, cpu = m.get("train_time_s"), m.get("train_cpu_s")
    text = f"{m.get('algo', '?').upper()}, {_n(steps)} steps" if steps else m.get("algo", "?").upper()
    if wall is not None:
        text += f", {wall / 60:.1f} min wall" + (f" / {cpu / 60:.1f} min CPU" if cpu is not None else "")
    return text


def load_agents(agents_dir: Path = AGENTS) -> list[dict[str, Any]]:
    """The sidecars of the agents (a zip beside its JSON), with ``name`` and ``robot`` (default the FER)."""
    out = []
    for p in sorted(agents_dir.glob("*.json")):
        if not p.with_suffix(".zip").is_file():
            continue
        m = json.loads(p.read_text())
        if m.get("env_id") not in ENVS:
            raise ValueError(f"{p}: env_id {m.get('env_id')!r} is not a registered env")
        out.append(m | {"name": p.stem, "robot": m.get("robot", "fer")})
    return out


def rows(agents: list[dict[str, Any]], scripted: dict[str, Any]) -> list[list[str]]:
    table = []
    for env in ENVS:
        for robot in ROBOTS:
            other = "fr3" if robot == "fer" else "fer"
            s = scripted.get("results", {}).get(env, {}).get(robot)
            if env in SCRIPTED_POLICIES:
                table.append([f"`{env}`", robot.upper(), f"scripted `{SCRIPTED_POLICIES[env]}`", _pct(s), _ttc(s, env),
                              "-", "-"])
            else:
                table.append([f"`{env}`", robot.upper(), "scripted: none in the package", "-", "-", "-", "-"])
            own = [a for a in agents if a["env_id"] == env and a["robot"] == robot]
            for a in own:
                table.append([f"`{env}`", robot.upper(), f"learned `{a['name']}`", _pct(a.get("evaluation")),
                              _ttc(a.get("evaluation"), env), _training(a), _pct(a.get("evaluation_other_robot"))
                              + f" on the {other.upper()}" if a.get("evaluation_other_robot") else "-"])
            if not own:
                cross = [a for a in agents if a["env_id"] == env and a["robot"] == other
                         and a.get("evaluation_other_robot")]
                for a in cross:
                    r = a.get("evaluation_other_robot")
                    table.append([f"`{env}`", robot.upper(), f"learned `{a['name']}` (trained on the "
                                  f"{other.upper()})", _pct(r), _ttc(r, env), "see its own row", "-"])
                if not cross:
                    table.append([f"`{env}`", robot.upper(), "learned: no agent shipped", "-", "-", "-", "-"])
    return table


def render(agents_dir: Path = AGENTS, scripted_path: Path = SCRIPTED) -> str:
    scripted = json.loads(scripted_path.read_text()) if scripted_path.is_file() else {}
    head = ["env", "robot", "policy", "success (episodes, seeds)", "mean time to converge", "training",
            "the same agent on the other robot"]
    lines = [BEGIN, "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in rows(load_agents(agents_dir), scripted)]
    if scripted:
        lines += ["", f"Scripted rows: `{scripted['command']}`, {scripted['date']} ({scripted['provenance']}). "
                  "Learned rows: each agent's sidecar (its `command`, `training_curve` and evaluations)."]
    lines += ["", END]
    return "\n".join(lines)


def replace_table(doc: str, table: str) -> str:
    if BEGIN not in doc or END not in doc:
        raise ValueError(f"{DOC.relative_to(ROOT)} lacks the markers {BEGIN!r} ... {END!r}")
    a = doc.index(BEGIN)
    b = doc.index(END) + len(END)
    return doc[:a] + table + doc[b:]


def evaluate_scripted(episodes: int = EPISODES, seed: int = SEED) -> dict[str, Any]:
    """Each env's scripted controller on each robot, ``episodes`` episodes from ``seed`` (franka_vs_gym.evaluate)."""
    import franka_vs_gym
    from franka_vs_gym import policies

    results: dict[str, dict[str, Any]] = {}
    for env, cls_name in SCRIPTED_POLICIES.items():
        for robot in ROBOTS:
            cls = getattr(policies, cls_name)
            kw: dict[str, Any] = {"robot": robot}
            if cls_name == "ComputedTorquePolicy":
                policy = cls(None, robot=robot)
                kw["action_type"] = "torque"
            else:
                policy = cls(robot=robot)
                kw |= {"action_type": "joint_velocity", "observation_type": "features"}
            t = time.perf_counter()
            r = franka_vs_gym.evaluate(policy, env, episodes, seed, env_kwargs=kw)
            summary = {k: v for k, v in r.items() if k in ("n_episodes", "success_rate", "mean_time_to_converge",
                                                            "median_final_error", "mean_length", "failures")}
            summary = {k: (None if isinstance(v, float) and v != v else v) for k, v in summary.items()}
            results.setdefault(env, {})[robot] = summary | {"seed": seed, "policy": cls_name, "env_kwargs": kw}
            print(f"{env:26s} {robot}: {cls_name:22s} success {r['success_rate']:.2f}, failures {r['failures']} "
                  f"({time.perf_counter() - t:.0f} s)", flush=True)
    return results


def figure(path: Path, agents_dir: Path = AGENTS) -> None:
    """The held-out success of every agent with a training curve, against training steps and process CPU time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for a in load_agents(agents_dir):
        curve = a.get("training_curve")
        if a.get("action_type") != "joint_velocity" or not curve or "steps" not in curve[0]:
            continue
        label = f"{a['name']} ({a['env_id']}, {a['robot'].upper()})"
        style = "-" if a["robot"] == "fer" else "--"
        for ax, key, scale in ((axes[0], "steps", 1e3), (axes[1], "cpu_s", 1.0)):
            if all(key in r for r in curve):
                ax.plot([r[key] / scale for r in curve], [r["success_rate"] for r in curve], style,
                        marker="o", ms=3, label=label)
    axes[0].set_xlabel("training steps (thousands)")
    axes[1].set_xlabel("process CPU time (s), one torch thread")
    axes[0].set_ylabel("success on 100 held-out episodes")
    for ax in axes:
        ax.axhline(0.95, color="grey", lw=0.8, ls=":")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="center right")
    fig.suptitle("Joint-velocity agents: PPO, the IBVS features recipe (solid: FER, dashed: FR3)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if docs/envs.md's table is out of date")
    ap.add_argument("--scripted", action="store_true", help="evaluate the scripted controllers again first "
                    f"({EPISODES} episodes per env and robot, seeds {SEED}...) into {SCRIPTED.relative_to(ROOT)}")
    ap.add_argument("--figure", default=None, help="also draw the agents' training curves into this PNG")
    args = ap.parse_args(argv)
    if args.check and args.scripted:
        ap.error("--check and --scripted exclude each other")
    if args.scripted:
        load0 = [round(x, 2) for x in os.getloadavg()]
        results = evaluate_scripted()
        SCRIPTED.write_text(json.dumps({
            "command": "python scripts/envs_table.py --scripted",
            "date": datetime.date.today().isoformat(),
            "provenance": f"2 cores shared, load {load0[0]} -> {round(os.getloadavg()[0], 2)}",
            "results": results}, indent=1) + "\n")
    try:
        doc = DOC.read_text()
        new = replace_table(doc, render())
    except ValueError as e:
        print(f"envs_table: error: {e}", file=sys.stderr)
        return 2
    if args.figure:
        figure(Path(args.figure))
        print(f"wrote {args.figure}")
    if args.check:
        if new != doc:
            print(f"{DOC.relative_to(ROOT)}'s table is out of date: run python scripts/envs_table.py",
                  file=sys.stderr)
            return 1
        return 0
    if new != doc:
        DOC.write_text(new)
        print(f"wrote the table of {DOC.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
