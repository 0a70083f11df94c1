"""The library of candidate physical effects a model may lack: one class per effect, one registry.

Every effect explains part of the inverse-dynamics residual ``r = tau_J - tau_model`` (N, 7) Nm by a contribution
that is **linear in its coefficients once its shape is chosen**:

``c = sum_p design[:, :, p] * theta_p`` (shared effects, ``theta`` (p,)), or, for per-joint effects,
``c[:, j] = sum_p design[:, j, p] * theta[j, p]`` (``theta`` (7, p), each joint independent).

Non-linear shape parameters (a Coulomb smoothing velocity, a sigmoid's width and centre) are chosen on the residual
the effect has to explain (:meth:`Effect.shape`); everything else is linear least squares, which lets
:mod:`franka_vs_gym.validation.selection` fit any set of effects *jointly* and cross-validate it from cached Gram
matrices. A class also says whether a fitted value is physically plausible (:meth:`Effect.problems`), applies itself
to a :class:`~franka_vs_gym.model.config.ModelConfig` (so the pinocchio model and the MuJoCo plant both get it:
:meth:`Effect.apply`), and injects itself into generated data (:meth:`Effect.inject`, used by the hidden-effect
generator). The registry (:data:`REGISTRY`) is the one list ``diagnose``, ``fit``, the generator and the tests read.

Users add effects by writing one subclass of :class:`Effect` in their own file and passing it with
``franka-vs diagnose LOG --effects my_effects.py`` (or ``load_plugin("my_effects.py")``, or an entry point in the
group ``franka_vs_gym.effects``); see docs/workbench/guide.md ("Add your own effect") for a complete example.

Layout: :mod:`.base` (context, fit record, :class:`Effect`), one module per family (:mod:`.friction`,
:mod:`.inertial`, :mod:`.sensor`, :mod:`.timing`) and :mod:`.registry` (the registry and plug-in loading).
"""

from franka_vs_gym.validation.effects.base import *  # noqa: F403
from franka_vs_gym.validation.effects.friction import *  # noqa: F403
from franka_vs_gym.validation.effects.inertial import *  # noqa: F403
from franka_vs_gym.validation.effects.registry import *  # noqa: F403
from franka_vs_gym.validation.effects.sensor import *  # noqa: F403
from franka_vs_gym.validation.effects.sigmoid import *  # noqa: F403
from franka_vs_gym.validation.effects.timing import *  # noqa: F403
