"""The one registry of effects that diagnose, fit, the generators and the tests read, and user plug-ins."""

from __future__ import annotations

import importlib.util
import inspect
import sys
from pathlib import Path

from franka_vs_gym.validation.effects.base import (
    Context,
    Effect,
    Fit,
    NotApplicable,
    PlantChange,
)
from franka_vs_gym.validation.effects.friction import (
    CoulombFriction,
    LoadDependentFriction,
    StribeckFriction,
    ViscousFriction,
)
from franka_vs_gym.validation.effects.inertial import (
    Armature,
    GravityTilt,
    LinkInertials,
    LinkMass,
    Payload,
)
from franka_vs_gym.validation.effects.sensor import (
    TorqueOffset,
)
from franka_vs_gym.validation.effects.sigmoid import AsymmetricFriction, SigmoidFriction
from franka_vs_gym.validation.effects.timing import (
    CommandDelay,
    Delay,
)


class EffectRegistry:
    """The one list of effects (name -> instance, with aliases) that diagnose, fit, the generators and the tests
    read. ``register(EffectClass)`` adds one (a user's plug-in, or a library extension); names must be unique."""

    def __init__(self) -> None:
        self._effects: dict[str, Effect] = {}
        self._aliases: dict[str, str] = {}

    def register(self, effect: type[Effect] | Effect, replace: bool = False) -> Effect:
        e = effect() if isinstance(effect, type) else effect
        if not isinstance(e, Effect):
            raise ValueError(f"{effect!r} is not an Effect subclass")
        if not e.name or not e.name.replace("_", "").isalnum():
            raise ValueError(f"effect class {type(e).__name__} needs a name made of letters, digits and '_'")
        if (e.name in self._effects or e.name in self._aliases) and not replace:
            raise ValueError(f"an effect named {e.name!r} is already registered")
        if type(e).design is Effect.design:
            raise ValueError(f"effect {e.name!r} must implement design(ctx, shape)")
        self._effects[e.name] = e
        for a in e.aliases:
            self._aliases[a] = e.name
        return e

    def unregister(self, name: str) -> None:
        e = self._effects.pop(name)
        for a in e.aliases:
            self._aliases.pop(a, None)

    def get(self, name: str) -> Effect:
        key = self._aliases.get(name.strip(), name.strip())
        if key not in self._effects:
            raise ValueError(f"unknown effect {name!r}: choose from {', '.join(self._effects)}")
        return self._effects[key]

    def names(self) -> list[str]:
        return list(self._effects)

    def injectable(self) -> list[str]:
        return [n for n, e in self._effects.items() if e.injectable]

    def __contains__(self, name: str) -> bool:
        return name in self._effects or name in self._aliases

    def __getitem__(self, name: str) -> Effect:
        return self.get(name)

    def __iter__(self):
        return iter(self._effects)

    def __len__(self) -> int:
        return len(self._effects)

    def items(self):
        return self._effects.items()

    def values(self):
        return self._effects.values()


REGISTRY = EffectRegistry()
for _cls in (ViscousFriction, CoulombFriction, SigmoidFriction, AsymmetricFriction, StribeckFriction,
             LoadDependentFriction, TorqueOffset, Armature, Payload, LinkMass, LinkInertials, GravityTilt, Delay):
    REGISTRY.register(_cls)
LIBRARY = REGISTRY  # the historical name
COMMAND_DELAY = CommandDelay()
FRICTION_EFFECTS = ("viscous_friction", "coulomb_friction", "sigmoid_friction", "asymmetric_friction",
                    "stribeck_friction", "load_dependent_friction")
ENTRY_POINT_GROUP = "franka_vs_gym.effects"


def get_effect(name: str) -> Effect:
    """The registered effect called ``name`` (or one of its aliases)."""
    return REGISTRY.get(name)


def load_plugin(path: str | Path, registry: EffectRegistry = REGISTRY, replace: bool = False) -> list[str]:
    """Import a user's Python file and register every :class:`Effect` subclass it defines (with a ``name``).
    Returns the names registered. Raises ValueError naming the problem (missing file, import error, no effect)."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"effects file not found: {p}")
    if p.suffix != ".py":
        raise ValueError(f"{p}: an effects plug-in must be a Python file (.py)")
    mod_name = f"franka_vs_gym_user_effects_{abs(hash(str(p.resolve())))}"
    spec = importlib.util.spec_from_file_location(mod_name, p)
    module = importlib.util.module_from_spec(spec)
    sys.modules[mod_name] = module
    try:
        spec.loader.exec_module(module)
    except Exception as exc:  # the user's code: report its error in one line
        sys.modules.pop(mod_name, None)
        raise ValueError(f"{p}: importing the effects file failed: {type(exc).__name__}: {exc}") from exc
    names = []
    for _, obj in inspect.getmembers(module, inspect.isclass):
        if issubclass(obj, Effect) and obj.__module__ == mod_name and obj.name:
            if obj.name in registry and not replace and type(registry.get(obj.name)) is obj:
                continue
            names.append(registry.register(obj, replace=replace).name)
    if not names:
        raise ValueError(f"{p}: defines no Effect subclass with a name")
    return names


def load_entry_points(registry: EffectRegistry = REGISTRY) -> list[str]:
    """Register the effects installed packages declare in the entry-point group ``franka_vs_gym.effects``."""
    from importlib.metadata import entry_points

    names = []
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        obj = ep.load()
        if ep.name in registry:
            continue
        names.append(registry.register(obj).name)
    return names


__all__ = ["COMMAND_DELAY", "Context", "Effect", "EffectRegistry", "ENTRY_POINT_GROUP", "Fit", "FRICTION_EFFECTS",
           "LIBRARY", "NotApplicable", "PlantChange", "REGISTRY", "get_effect", "load_entry_points", "load_plugin"]
