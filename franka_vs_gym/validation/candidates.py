"""The candidate effects of a diagnosis: the registered library, the effects installed packages declare (entry
points, read once per process) and plug-in files named on the command line."""

from __future__ import annotations

from franka_vs_gym.validation.compare import progress
from franka_vs_gym.validation.effects import REGISTRY, Effect, EffectRegistry, load_entry_points, load_plugin

_ENTRY_POINTS_LOADED = False


def _installed_plugins() -> None:
    """Register, once per process, the effects installed packages declare in the entry-point group
    ``franka_vs_gym.effects``; a broken plug-in is reported in one line, not fatal to the library."""
    global _ENTRY_POINTS_LOADED
    if _ENTRY_POINTS_LOADED:
        return
    _ENTRY_POINTS_LOADED = True
    try:
        load_entry_points()
    except Exception as exc:  # a third party's package: say which, keep the library usable
        progress(f"warning: an installed effect plug-in failed to load: {type(exc).__name__}: {exc}")


def resolve_effects(effects: list[str] | None, registry: EffectRegistry = REGISTRY) -> list[Effect]:
    """Candidate effects: every registered effect, or the names given; an item ending in ``.py`` is a plug-in file
    whose effects are registered and added to the candidates."""
    if registry is REGISTRY:
        _installed_plugins()
    if effects is None:
        return list(registry.values())
    out: list[Effect] = []
    plugins_only = True
    for item in effects:
        item = item.strip()
        if not item:
            continue
        if item.endswith(".py"):
            for n in load_plugin(item, registry):
                out.append(registry.get(n))
            continue
        plugins_only = False
        out.append(registry.get(item))
    if plugins_only:  # only plug-in files: rank them with the whole library
        out = list(registry.values())
    seen, uniq = set(), []
    for e in out:
        if e.name not in seen:
            seen.add(e.name)
            uniq.append(e)
    return uniq


__all__ = ["resolve_effects"]
