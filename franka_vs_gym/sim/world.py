"""The MuJoCo world: one compiled scene, one MjData, synchronous stepping of every robot in it."""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np

from franka_vs_gym.assets.mjcf import SceneSpec, scene_xml
from franka_vs_gym.sim.rendering import SharedRenderers, make_renderer, render_view


class SimulationDiverged(RuntimeError):
    """The physics produced NaN/inf or unbounded values; the state is no longer meaningful."""


_BAD_WARNINGS = {
    int(mujoco.mjtWarning.mjWARN_BADQPOS): "joint positions became NaN/inf or unbounded",
    int(mujoco.mjtWarning.mjWARN_BADQVEL): "joint velocities became NaN/inf or unbounded",
    int(mujoco.mjtWarning.mjWARN_BADQACC): "joint accelerations became NaN/inf or unbounded",
}


def no_op() -> None:
    """A pre-step hook that does nothing (a robot whose per-step effects all run inside MuJoCo's step)."""


class SimWorld:
    """A compiled MuJoCo scene stepped in simulated time.

    Each robot registers a pre-step hook (friction, command delay...) that runs before every ``mj_step``, so several
    robots in one scene advance synchronously. Time is the simulator's (``time``, seconds).

    Parameters
    ----------
    scene : SceneSpec
        What to build (robots, table, tags, time step).
    """

    def __init__(self, scene: SceneSpec | None = None) -> None:
        self.scene = scene if scene is not None else SceneSpec()
        self.xml = scene_xml(self.scene)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        self.dt = float(self.model.opt.timestep)
        self._hooks: list[Callable[[], None]] = []
        self._active: list[Callable[[], None]] = []  # the hooks that do something
        self._post_hooks: list[Callable[[], None]] = []
        self._checks: list[Callable[[], None]] = []  # run after every step(n) call (the robots' reflexes)
        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {}
        self._shared: SharedRenderers | None = None
        self.diverged: str | None = None
        self._wn = self.data.warning.number  # live view of MuJoCo's warning counters
        self._w_pos, self._w_vel, self._w_acc = (int(mujoco.mjtWarning.mjWARN_BADQPOS),
                                                 int(mujoco.mjtWarning.mjWARN_BADQVEL),
                                                 int(mujoco.mjtWarning.mjWARN_BADQACC))

    def add_pre_step(self, hook: Callable[[], None]) -> None:
        self._hooks.append(hook)
        self._active = [h for h in self._hooks if h is not no_op]

    def replace_pre_step(self, old: Callable[[], None], new: Callable[[], None]) -> None:
        self._hooks[self._hooks.index(old)] = new
        self._active = [h for h in self._hooks if h is not no_op]

    def add_post_step(self, hook: Callable[[], None]) -> None:
        self._post_hooks.append(hook)

    def add_check(self, check: Callable[[], None]) -> None:
        """A check run after every ``step(n)`` call, e.g. a robot's reflexes (the compiled plant checks them at
        every physics step inside the call and records a violation; the check raises it); it may raise to stop the
        caller."""
        self._checks.append(check)

    @property
    def time(self) -> float:
        """Simulated time, s."""
        return float(self.data.time)

    def step(self, n: int = 1) -> None:
        """Advance ``n`` physics steps. Raises SimulationDiverged if the physics blew up."""
        m, d, step, wn = self.model, self.data, mujoco.mj_step, self._wn
        a, b, c = self._w_pos, self._w_vel, self._w_acc
        post = self._post_hooks
        if not self._active and not post:  # every effect inside MuJoCo's step (compiled plant): one call
            step(m, d, n)
            if wn[a] or wn[b] or wn[c]:
                self._diverge()
            for check in self._checks:
                check()
            return
        if len(self._active) == 1 and not post:  # one robot, no post-step work: the 1 kHz fast path
            h = self._active[0]
            for _ in range(n):
                h()
                step(m, d)
                if wn[a] or wn[b] or wn[c]:  # MuJoCo found NaN/inf/huge values (and auto-reset the state)
                    self._diverge()
            for check in self._checks:
                check()
            return
        hooks = self._active
        for _ in range(n):
            for h in hooks:
                h()
            step(m, d)
            if wn[a] or wn[b] or wn[c]:
                self._diverge()
            for h in post:
                h()
        for check in self._checks:
            check()

    def after_steps(self) -> None:
        """What :meth:`step` does after its physics, for code that called ``mujoco.mj_step`` itself on this world's
        model and data (every effect inside MuJoCo's step): raises SimulationDiverged if MuJoCo warned of a diverging
        state, then runs the robots' checks (their reflexes)."""
        wn = self._wn
        if wn[self._w_pos] or wn[self._w_vel] or wn[self._w_acc]:
            self._diverge()
        for check in self._checks:
            check()

    def _diverge(self) -> None:
        reasons = [msg for w, msg in _BAD_WARNINGS.items() if self._wn[w] > 0]
        self.diverged = "; ".join(reasons) or "the simulation state was reset by MuJoCo"
        self._wn[:] = 0  # re-arm detection for the next episode
        raise SimulationDiverged(f"simulation diverged at t={self.data.time:.4f}s: {self.diverged}")

    def forward(self) -> None:
        mujoco.mj_forward(self.model, self.data)

    # ------------------------------------------------------------------ rendering
    def renderer(self, width: int, height: int) -> mujoco.Renderer:
        """A cached offscreen renderer (headless: set MUJOCO_GL=egl or osmesa; chosen automatically), or the shared
        one of :meth:`share_renderers`. Draw through :func:`franka_vs_gym.sim.rendering.render_view` with this
        world's model and data (a shared renderer belongs to another model with the same visual assets)."""
        if self._shared is not None:
            return self._shared.renderer(width, height)
        key = (width, height)
        if key not in self._renderers:
            self._renderers[key] = make_renderer(self.model, width, height)
        return self._renderers[key]

    def share_renderers(self, pool: SharedRenderers) -> bool:
        """Draw this world's images through ``pool`` (one OpenGL context for many worlds of the same scene) when its
        model's visual assets are the pool's; returns whether it does. Images are unchanged."""
        if pool.accepts(self.model):
            self._shared = pool
            return True
        return False

    def render(self, camera: str | int = "overview", width: int = 640, height: int = 480) -> np.ndarray:
        """RGB image (height, width, 3) uint8 from a named camera."""
        return render_view(self.renderer(width, height), self.model, self.data, camera)

    def close(self) -> None:
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()
        self._shared = None
