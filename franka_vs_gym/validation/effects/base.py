"""The base of every effect: the fitting context, the fit record, the plant change of the generators and the
:class:`Effect` class with its shared helpers."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from franka_vs_gym.model.config import ModelConfig, RigidBody
from franka_vs_gym.model.description import FER
from franka_vs_gym.model.friction import (
    gaz_sigmoid,
)
from franka_vs_gym.validation.evaluate import ModelEvaluation, evaluate, sigmoid_friction
from franka_vs_gym.validation.signals import ProcessedLog

TAU_MAX = FER.limit_arrays()["tau_max"]  # the FER's; effects judge with their context's robot (_tau_max)


def _tau_max(ctx) -> np.ndarray:
    """Joint torque limits (7,) Nm of the robot the context's model describes."""
    return ctx.config.robot.limit_arrays()["tau_max"]


def _model_step_levels(ctx) -> tuple[np.ndarray, np.ndarray]:
    """The baseline model's dry-friction levels (7,) each, Nm: the magnitude of its step friction while a joint
    slides positively (``L_plus``) and negatively (``L_minus``), from all its step terms: the sigmoid's asymptotes
    (``phi1 (1 - s0)`` and ``phi1 s0`` with ``s0 = 1 / (1 + exp(-phi2 phi3))``) plus the Coulomb term. A friction
    correction is physical when the *total* level it leaves in each direction is >= 0: a robot with less friction
    than the model (another unit, a warm joint) is corrected by a negative step, which must not be refused."""
    fr = ctx.config.friction
    phi1, phi2, phi3 = (np.asarray(x, dtype=np.float64) for x in (fr.phi1, fr.phi2, fr.phi3))
    s0 = 1.0 / (1.0 + np.exp(-np.clip(phi2 * phi3, -50.0, 50.0)))
    c = np.asarray(fr.coulomb, dtype=np.float64)
    return phi1 * (1.0 - s0) + c, phi1 * s0 + c
SIG_PHI2 = np.geomspace(2.0, 100.0, 12)  # s/rad
SIG_PHI3 = np.array([-0.08, -0.04, 0.0, 0.04, 0.08])  # rad/s
COULOMB_VC = (0.005, 0.01, 0.02, 0.05, 0.1)  # rad/s, Coulomb smoothing velocities tried
STRIBECK_VS = (0.02, 0.05, 0.1, 0.2)  # rad/s, Stribeck velocities tried
MAX_PAYLOAD = 3.5  # kg (FER rated payload 3 kg, plus margin)
MAX_DELAY = 0.1  # s
MIN_DELAY = 0.0015  # s: 1.5 ticks of the FER's 1 kHz control cycle (the shortest lag the delay effect reports)
MAX_TILT = math.radians(30.0)


MOTOR_COULOMB_VEL = 0.02  # rad/s: velocity scale of the motor-side Coulomb column tanh(dq / v)


def motor_terms(data) -> np.ndarray:
    """(N, 7, 4) per joint, what lies between the commanded torque and a link-side torque sensor besides gravity:
    ``ddq`` (the motors' reflected inertia, the effective armature ``RobotDescription.rotor_inertia``, enters as
    ``-I_r ddq``), ``dq`` and ``tanh(dq / MOTOR_COULOMB_VEL)`` (viscous and Coulomb friction on the motor side of
    the sensor) and a constant (a sensor offset)."""
    dq = data.dq
    return np.stack([data.ddq, dq, np.tanh(dq / MOTOR_COULOMB_VEL), np.ones_like(dq)], axis=2)


def without_motor_terms(data, y: np.ndarray) -> np.ndarray:
    """``y`` (N, 7) minus, per joint, its least-squares fit on :func:`motor_terms`. On a robot with joint torque
    sensors ``tau_J - g(q) - tau_J_d`` is ``-I_r ddq`` minus the motor-side friction even without any delay (on the
    simulated FER with its effective armature: 0.08-0.21 Nm RMS in a PD-controlled sine motion, which a delay fit
    on the raw difference took for a 12 ms command delay). Removing these terms from the residual and from the
    delay's column alike gives the delay coefficient of the joint regression (Frisch-Waugh-Lovell) with the motor
    terms' coefficients free per joint, and scores the delay only on what they cannot explain."""
    Z = motor_terms(data)
    out = np.empty_like(y, dtype=float)
    for j in range(y.shape[1]):
        coef, *_ = np.linalg.lstsq(Z[:, j], y[:, j], rcond=None)
        out[:, j] = y[:, j] - Z[:, j] @ coef
    return out


class Context:
    """What every effect needs, built once per diagnosis: the processed log ``data``, the baseline configuration
    ``config``, its evaluation ``ev`` (with the gravity and full joint-torque regressors), the baseline residual
    ``residual`` (N, 7) Nm, the time derivative of the predicted torque ``dpred`` (N, 7) Nm/s, and the per-link
    torques ``link_torque`` (N, 7, 7) Nm (``[:, :, i]`` = the torque link i+1's own inertial parameters produce)."""

    def __init__(self, data: ProcessedLog, config: ModelConfig) -> None:
        self.data = data
        self.config = config
        self.ev: ModelEvaluation = evaluate(config, data, regressors=True)
        self.residual = data.tau - self.ev.predicted
        self.dpred = np.gradient(self.ev.predicted, data.time, axis=0)
        self.base_sigmoid = sigmoid_friction(config.friction, data.dq)
        self.n = data.n
        # decimated sample set for non-linear shape searches (the signals are low-passed far below 1 kHz)
        self.coarse = np.arange(0, self.n, max(1, int(round(data.settings.rate / 250.0))))
        self._sig_basis: np.ndarray | None = None
        self._cache: dict[Any, Any] = {}
        cmd = data.optional.get("tau_J_d")
        self.cmd_residual = self.dcmd = None
        if cmd is not None:
            from scipy import signal

            sos = signal.butter(data.settings.order, data.settings.cutoff, fs=data.settings.rate, output="sos")
            dcmd = np.gradient(signal.sosfiltfilt(sos, cmd, axis=0), data.time, axis=0)
            # the motors between command and link-side sensor (-I_r ddq, friction, offset) are not a residual
            self.cmd_residual = without_motor_terms(data, data.tau - self.ev.gravity - cmd)
            self.dcmd = dcmd - dcmd.mean(axis=0)

    def cached(self, key: Any, make) -> Any:
        """A value computed once per context (designs that do not depend on the residual)."""
        if key not in self._cache:
            self._cache[key] = make()
        return self._cache[key]

    @property
    def link_params(self) -> np.ndarray:
        """(7, 10) pinocchio dynamic parameters of links 1..7 (without tool), in their joint frames."""
        return self.cached("link_params", lambda: np.array([
            pin.Inertia(m, np.asarray(c), np.asarray(inertia)).toDynamicParameters()
            for m, c, inertia in self.config.link_inertials()]))

    @property
    def link_torque(self) -> np.ndarray:
        return self.cached("link_torque", lambda: np.einsum("njlp,lp->njl",
                                                            self.ev.Y.reshape(self.n, 7, 7, 10), self.link_params))

    def sigmoid_basis(self) -> np.ndarray:
        """(n_grid, n_coarse, 7) sigmoid shapes s(dq) = 1/(1+exp(-phi2 (dq+phi3))) - 1/(1+exp(-phi2 phi3))."""
        if self._sig_basis is None:
            dq = self.data.dq[self.coarse]
            out = []
            for p2 in SIG_PHI2:
                for p3 in SIG_PHI3:
                    out.append(gaz_sigmoid(dq, 1.0, p2, p3))
            self._sig_basis = np.array(out)
        return self._sig_basis


@dataclass
class Fit:
    """One fitted effect: ``theta`` (``{"coef": (7, p) or (p,), **shape}``, effect-specific), ``joints`` the joints
    a per-joint effect applies to (all seven for a shared effect)."""

    effect: str
    theta: dict[str, Any]
    joints: list[int] = field(default_factory=lambda: list(range(7)))


@dataclass
class PlantChange:
    """What effects injected into a simulated plant: the plant's configuration, an undeclared payload (a body the
    controller's model does not know) and a measurement delay (s) of the torque sensor."""

    config: ModelConfig = field(default_factory=ModelConfig)
    payload: RigidBody | None = None
    measurement_delay: float = 0.0


class NotApplicable(ValueError):
    """The effect cannot be written into a ModelConfig (the model and the plant have no term for it)."""


def _lstsq_joints(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Per-column least squares of Y (m, 7) on X (m, 7): theta (7,)."""
    den = np.einsum("mj,mj->j", X, X)
    num = np.einsum("mj,mj->j", X, Y)
    return np.where(den > 1e-12, num / np.maximum(den, 1e-12), 0.0)


class Effect:
    """Base class of an effect (the plug-in interface).

    Class attributes: ``name`` (what ``--add`` and the JSON say), ``aliases``, ``per_joint`` (independent
    coefficients per joint, or shared by all), ``n_params`` (coefficients per joint, or in total, used in the
    information criterion; may exceed the linear columns when the shape has free parameters), ``signature`` (what
    it looks like in the residual), ``plausible`` (the physical range accepted), ``description``.

    A subclass implements :meth:`design` (and :meth:`shape` when it has non-linear shape parameters),
    :meth:`apply` and :meth:`inject`; :meth:`problems` and :meth:`public` have sensible defaults.
    """

    name = ""
    aliases: tuple[str, ...] = ()
    per_joint = True
    n_params = 1
    description = ""
    signature = ""
    plausible = ""
    injectable = True
    #: order of magnitude of the effect in generated data at magnitude 1 (documentation only)
    typical = ""
    #: ridge prior, relative to the diagonal of the effect's normal equations: shrinks the coefficients the log
    #: barely excites toward zero (0: plain least squares)
    ridge = 0.0
    #: the law's step height does not depend on the pose or load (tested by the lack-of-fit test's ``pose``
    #: alternative, :mod:`~franka_vs_gym.validation.lackfit`)
    lof_constant_height = False
    #: the processed log's signals the law depends on (e.g. ``("dq",)``), the default :meth:`lof_drivers`
    lof_signals: tuple[str, ...] = ()
    #: why the effect cannot be written into a model configuration (effects without :meth:`apply`; one line)
    not_applicable = "the model and the plant have no term for it"

    def lof_drivers(self, ctx: Context) -> dict[str, np.ndarray]:
        """The variables the law says the effect depends on, name -> (N, 7) per joint (the lack-of-fit test compares
        the fitted law with a nonparametric function of them); ``{}``: the effect's own contribution is used.
        By default the log signals named in ``lof_signals``; override for derived variables."""
        return {name: getattr(ctx.data, name) for name in self.lof_signals}

    # --- the linear model ------------------------------------------------------------------------------------
    def shape(self, ctx: Context, target: np.ndarray) -> dict[str, Any]:
        """Non-linear shape parameters chosen on ``target`` (N, 7) Nm, the residual this effect should explain;
        ``{}`` for purely linear effects."""
        return {}

    def design(self, ctx: Context, shape: dict[str, Any]) -> np.ndarray:
        """(N, 7, p) regressor columns for the given shape (Nm per unit coefficient)."""
        raise NotImplementedError

    def shape_key(self, shape: dict[str, Any]) -> tuple:
        """Hashable key of a shape (designs are cached by it)."""
        return tuple((k, np.asarray(v).round(9).tobytes()) for k, v in sorted(shape.items()))

    def make_fit(self, ctx: Context, coef: np.ndarray, shape: dict[str, Any], joints: list[int] | None) -> Fit:
        """A Fit from linear coefficients ((7, p) per joint with zeros off ``joints``, or (p,))."""
        return Fit(self.name, {"coef": np.asarray(coef, dtype=float), **shape},
                   list(range(7)) if joints is None else list(joints))

    def coef(self, fit: Fit) -> np.ndarray:
        c = np.asarray(fit.theta["coef"], dtype=float)
        if self.per_joint:
            c = c.reshape(7, -1).copy()
            off = [j for j in range(7) if j not in fit.joints]
            c[off] = 0.0
        return c

    def fit(self, ctx: Context, y: np.ndarray, idx: np.ndarray) -> Fit:
        """Least-squares fit on samples ``idx`` of target ``y`` (N, 7), all joints."""
        shape = self.shape(ctx, y)
        X = self.design(ctx, shape)[idx]
        if self.per_joint:
            A = np.einsum("mjp,mjq->jpq", X, X)
            b = np.einsum("mjp,mj->jp", X, y[idx])
            coef = np.array([_solve(A[j], b[j]) for j in range(7)])
        else:
            A = np.einsum("mjp,mjq->pq", X, X)
            b = np.einsum("mjp,mj->p", X, y[idx])
            coef = _solve(A, b)
        return self.make_fit(ctx, coef, shape, None)

    def contribution(self, ctx: Context, fit: Fit) -> np.ndarray:
        """(N, 7) Nm added to the model's torque by this effect (zero on joints not in ``fit.joints``)."""
        D = self.design(ctx, {k: v for k, v in fit.theta.items() if k != "coef"})
        c = self.coef(fit)
        return np.einsum("njp,jp->nj", D, c) if self.per_joint else D @ c

    def refine(self, ctx: Context, y: np.ndarray, fit: Fit) -> Fit:
        """Optional non-linear refinement on all samples (the final fit of ``franka-vs fit`` only)."""
        return fit

    # --- physics -----------------------------------------------------------------------------------------------
    def problems(self, ctx: Context, fit: Fit) -> dict[int, str]:
        """Plausibility problems by joint (key -1 for the whole effect); empty when plausible."""
        return {}

    def apply(self, config: ModelConfig, fit: Fit) -> ModelConfig:
        """The configuration with this effect added (model and plant); raises NotApplicable if it cannot be."""
        raise NotApplicable(f"effect {self.name!r} cannot be written into a model configuration: {self.not_applicable}")

    def constrain(self, ctx: Context, config: ModelConfig, fit: Fit) -> tuple[Fit, str | None]:
        """The fit as ``config`` can take it with a physically valid result (e.g. a friction law that still opposes
        motion): ``(fit, None)`` when nothing needs constraining, else the constrained fit and one line saying what
        was constrained. ``franka-vs fit`` calls it before :meth:`apply`; the default constrains nothing."""
        return fit, None

    def inject(self, plant: PlantChange, rng: np.random.Generator, magnitude: float) -> dict[str, Any]:
        """Put this effect, of a size drawn from ``rng`` and scaled by ``magnitude``, into a simulated plant (in
        place); returns the true parameters (the answer)."""
        raise NotImplementedError(f"effect {self.name!r} cannot inject itself into generated data")

    def public(self, fit: Fit) -> dict[str, Any]:
        """JSON-able parameters with units in the names."""
        c = self.coef(fit)
        out: dict[str, Any] = {"coef": np.round(c, 6).tolist()}
        for k, v in fit.theta.items():
            if k != "coef":
                out[k] = np.round(np.asarray(v, dtype=float), 6).tolist()
        return out

    def tilt_deg(self, ctx: Context, fit: Fit) -> float | None:  # only gravity_tilt answers
        return None

    def __repr__(self) -> str:
        return f"<effect {self.name}>"


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    scale = np.sqrt(np.maximum(np.diag(A), 1e-300))
    An = A / np.outer(scale, scale)
    return np.linalg.solve(An + 1e-10 * np.eye(len(b)), b / scale) / scale


def _joint_coef(fit: Fit, p: int = 1) -> np.ndarray:
    c = np.asarray(fit.theta["coef"], dtype=float).reshape(7, p).copy()
    c[[j for j in range(7) if j not in fit.joints]] = 0.0
    return c


# ---------------------------------------------------------------------------------------------- joint friction
def _vc_choice(ctx: Context, target: np.ndarray, law, grid=None) -> float:
    """The velocity of ``grid`` (default COULOMB_VC, or the model's Coulomb smoothing when it has Coulomb friction)
    whose column ``law(dq, v)`` explains ``target`` best (coarse samples)."""
    fr = ctx.config.friction
    if grid is None and fr.coulomb.any():
        return fr.coulomb_vel
    grid = COULOMB_VC if grid is None else grid
    dq, y = ctx.data.dq[ctx.coarse], target[ctx.coarse]
    best, best_sse = grid[0], np.inf
    for vc in grid:
        X = law(dq, vc)
        th = _lstsq_joints(X, y)
        sse = float(np.sum((y - X * th) ** 2))
        if sse < best_sse:
            best, best_sse = vc, sse
    return best


