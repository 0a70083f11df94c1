"""The plant's friction inside MuJoCo's step (franka_vs_gym.sim.plant): the same law as the model library's, per
robot and per model, in single worlds, two-robot scenes and mujoco.batch, and the pure-Python fallback."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import run_in_both_plants

from franka_vs_gym.assets.mjcf import RobotSpec, SceneSpec
from franka_vs_gym.model.config import Friction, ModelConfig
from franka_vs_gym.model.friction import joint_friction
from franka_vs_gym.sim import FORCE_TORQUE, JOINT_STATE, FrankaSim, SimWorld, plant

native = pytest.mark.skipif(not plant.NATIVE, reason=f"compiled plant unavailable: {plant.unavailable_reason()}")


def _law(fr: Friction, dq: np.ndarray) -> np.ndarray:
    """The model library's friction law (franka_vs_gym.model.friction), the reference of the plant."""
    return joint_friction(dq, fr.phi1, fr.phi2, fr.phi3, fr.viscous, fr.coulomb, fr.coulomb_vel, fr.stribeck,
                          fr.stribeck_vel)


def _custom_friction(seed: int) -> Friction:
    rng = np.random.default_rng(seed)
    return Friction(phi1=rng.uniform(0.2, 1.0, 7), phi2=rng.uniform(2.0, 60.0, 7), phi3=rng.uniform(-0.1, 0.1, 7),
                    viscous=rng.uniform(0.0, 0.5, 7), coulomb=rng.uniform(0.0, 0.4, 7), coulomb_vel=0.02)


def _stribeck_friction(seed: int) -> Friction:
    """A custom law with a Stribeck term (heights 0.1-1 Nm, Stribeck velocities 0.02-0.3 rad/s) on six joints."""
    fr = _custom_friction(seed)
    rng = np.random.default_rng(seed + 100)
    fr.stribeck = rng.uniform(0.1, 1.0, 7) * (np.arange(7) != 3)
    fr.stribeck_vel = rng.uniform(0.02, 0.3, 7)
    return fr


def test_the_extension_builds_with_this_machines_compiler(tmp_path):
    """What ``pip install -e .`` does on a machine with a C compiler: setup.py builds the compiled plant against the
    installed MuJoCo's headers, and the module loads and matches this MuJoCo and franka_vs_gym.sim.plant."""
    import importlib.util

    if not (shutil.which("cc") or shutil.which("gcc")):
        pytest.skip("no C compiler on this machine: the documented pure-Python fallback applies")
    root = Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--build-lib", str(tmp_path / "lib"),
                        "--build-temp", str(tmp_path / "tmp")], cwd=root, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    built = list((tmp_path / "lib").rglob("_plant*.so")) + list((tmp_path / "lib").rglob("_plant*.pyd"))
    assert built, r.stderr[-2000:]  # optional=True would hide a failed build: it must not have failed here
    spec = importlib.util.spec_from_file_location("_plant", built[0])
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.MJ_VERSION_HEADER == mujoco.mj_version()
    assert mod.TAG == plant.TAG and mod.NUSER == plant.NUSER and mod.callback_address() > 0


@native
@pytest.mark.parametrize("custom", [False, True, "stribeck"])
def test_plant_friction_equals_model_library(custom):
    """At random joint velocities the torque MuJoCo's callback applies is the model library's law to 1e-12 Nm,
    also after a friction scale (domain randomisation) and never when the plant's friction is off; with a Stribeck
    term too (velocities also near its Stribeck velocities)."""
    fr = {False: None, True: _custom_friction(3), "stribeck": _stribeck_friction(3)}[custom]
    cfg = ModelConfig(friction=fr) if custom else ModelConfig()
    sim = FrankaSim(cfg, camera=False)
    m, d, dofs = sim.world.model, sim.world.data, np.arange(sim._vs.start, sim._vs.stop)
    rng = np.random.default_rng(1)
    for k in (1.0, 0.7):
        sim.set_friction_scale(k)
        for _ in range(20):
            dq = rng.uniform(-2.5, 2.5, 7) * rng.choice([1.0, 1e-3], 7)
            if custom == "stribeck":
                dq = dq * rng.choice([1.0, 0.05], 7)
            d.qvel[dofs] = dq
            np.testing.assert_allclose(plant.plant_friction_torque(m, d, dofs), k * _law(cfg.friction, dq), rtol=0,
                                       atol=1e-12)
    sim.friction_enabled = False
    d.qvel[dofs] = 1.0
    assert np.all(plant.plant_friction_torque(m, d, dofs) == 0.0)
    assert np.all(sim._qfrc_applied == 0.0)  # nothing is left for Python to apply


@native
def test_two_robots_in_one_scene_get_their_own_friction():
    cfgs = [ModelConfig(friction=_custom_friction(5)), ModelConfig()]
    world = SimWorld(SceneSpec(robots=[RobotSpec(prefix="r0_", config=cfgs[0], camera=False),
                                       RobotSpec(prefix="r1_", base_pos=(0.0, 0.8, 0.0), config=cfgs[1],
                                                 camera=False)], table=False))
    sims = [FrankaSim(world=world, prefix=p) for p in ("r0_", "r1_")]
    rng = np.random.default_rng(2)
    for _ in range(10):
        dqs = [rng.uniform(-2, 2, 7) for _ in sims]
        for s, dq in zip(sims, dqs, strict=True):
            world.data.qvel[s._vs] = dq
        for s, dq, cfg in zip(sims, dqs, cfgs, strict=True):
            tau = plant.plant_friction_torque(world.model, world.data, np.arange(s._vs.start, s._vs.stop))
            np.testing.assert_allclose(tau, _law(cfg.friction, dq), rtol=0, atol=1e-12)


@native
def test_batch_of_models_with_randomised_friction_is_bit_identical_to_single_steps():
    """mujoco.batch on two threads, each simulation on its own model (own friction scale): the same trajectory,
    bit for bit, as stepping each robot alone, and different friction gives different motion."""
    from mujoco import batch as mjbatch

    sims = []
    for k in (0.5, 1.0, 1.5):
        s = FrankaSim(camera=False, reflexes=False)  # 2 Nm on the wrist passes its velocity limit: plant physics
        s.set_friction_scale(k)
        s.set_robot_state(FORCE_TORQUE)
        s.set_force_torque(JOINT_STATE, np.full(7, 2.0))
        sims.append(s)
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    b = mjbatch.Batch(sims[0].world.model, len(sims), nthread=2)
    b.set_models([s.world.model for s in sims])
    for i, s in enumerate(sims):
        mujoco.mj_getState(s.world.model, s.world.data, b.state[i], spec)
    b.step(nstep=200)
    for i, s in enumerate(sims):
        s.world.step(200)
        ref = np.zeros(b.nstate)
        mujoco.mj_getState(s.world.model, s.world.data, ref, spec)
        assert np.array_equal(ref, b.state[i])
    q = [s.get_position() for s in sims]
    assert not np.allclose(q[0], q[2], atol=1e-4)


@native
@pytest.mark.parametrize("stribeck", [False, True])
def test_pure_python_fallback_gives_the_same_motion(stribeck):
    """FRANKA_VS_GYM_PURE_PYTHON=1 applies the same law from Python: the same trajectory to 1e-9 rad (reflexes off:
    the wrist reaches its hard stop, which the reflexes would report as joint_position_limits_violation), also
    with a Stribeck term in the law."""
    model = ("ModelConfig(friction=Friction(stribeck=[0.8, 0.8, 0.5, 0.5, 0.3, 0.3, 0.2], stribeck_vel=[0.05] * 7))"
             if stribeck else "None")
    code = ("import numpy as np; from franka_vs_gym.sim import FrankaSim, FORCE_TORQUE, JOINT_STATE, plant;"
            "from franka_vs_gym.model.config import Friction, ModelConfig;"
            f"s = FrankaSim({model}, camera=False, reflexes=False); s.set_friction_scale(0.8);"
            "s.set_robot_state(FORCE_TORQUE);"
            "s.set_force_torque(JOINT_STATE, [3, -2, 1, 2, 0.5, -0.5, 0.3]); s.wait(0.5);"
            "print(plant.NATIVE, *s.get_position().tolist())")
    out = {}
    for flag, stdout in run_in_both_plants(code).items():
        words = stdout.split()
        out[flag] = (words[0], np.array([float(w) for w in words[1:]]))
    assert out["0"][0] == "True" and out["1"][0] == "False"
    np.testing.assert_allclose(out["0"][1], out["1"][1], rtol=0, atol=1e-9)
    assert np.abs(out["0"][1] - FrankaSim(camera=False).get_position()).max() > 0.05  # the robot moved


def test_pure_python_fallback_friction_equals_model_library():
    """FRANKA_VS_GYM_PURE_PYTHON=1: the Python friction step (into qfrc_applied) is the model library's law to
    1e-12 Nm at random velocities, with a Stribeck term and a friction scale."""
    code = ("import numpy as np, sys; sys.path.insert(0, 'tests'); from test_plant import _stribeck_friction, _law;"
            "from franka_vs_gym.model.config import ModelConfig; from franka_vs_gym.sim import FrankaSim, plant;"
            "fr = _stribeck_friction(3); s = FrankaSim(ModelConfig(friction=fr), camera=False);"
            "s.set_friction_scale(0.7); rng = np.random.default_rng(4); err = 0.0\n"
            "for _ in range(50):\n"
            "    dq = rng.uniform(-2.5, 2.5, 7) * rng.choice([1.0, 0.05, 1e-3], 7); s._qvel[:] = dq;"
            " s._friction_step(); err = max(err, np.abs(-s._qfrc_applied - 0.7 * _law(fr, dq)).max())\n"
            "print(plant.NATIVE, err, np.abs(_law(fr, np.full(7, 0.05))).max())")
    env = dict(os.environ, FRANKA_VS_GYM_PURE_PYTHON="1")
    r = subprocess.run([sys.executable, "-W", "ignore", "-c", code], env=env, capture_output=True, text=True,
                       cwd=Path(__file__).resolve().parents[1])
    assert r.returncode == 0, r.stderr[-2000:]
    native_flag, err, size = r.stdout.split()
    assert native_flag == "False" and float(err) <= 1e-12 and float(size) > 0.1
