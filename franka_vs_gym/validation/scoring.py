"""The scoring words of the workbench's evaluation, defined once: how the answer of ``diagnose`` on a copy of a real
recording with known effects added (:mod:`franka_vs_gym.validation.injected`) is judged, as the *change* from the
untouched copy's answer at the same rate.

- **right**: every injected effect is named on its joints (an accepted law: a Coulomb step may be named Coulomb,
  sigmoid, asymmetric or Stribeck friction; a payload's fitted mass change within 50 % of the injected one, a tilt's
  change of the gravity vector within 50 % of the injected one) and nothing absent is newly named;
- **ambiguous**: not right, but every injected effect is either named or among at most :data:`MAX_CANDIDATES`
  candidates the answer says it cannot tell apart (an ``ambiguous`` entry on a joint it touches);
- **confident wrong**: an effect newly named (beyond the untouched copy's answer) on a joint where it was not
  injected, while the answer neither flags that joint as unexplained nor lists that name as ambiguous there. This
  outranks the others: one confident wrong name makes the case confident wrong;
- **flagged**: none of the above, and the answer newly flags a touched joint as unexplained (a structure test
  finding beyond the untouched copy's) or, for a grasp, reports a model change. For an effect outside the library
  this is the right answer;
- **missed**: the rest (nothing wrong named, the injected effect neither named nor flagged).

An effect outside the library (cogging, a cable spring, crosstalk) is never *right*: it is *flagged* when the answer
flags it, *confident wrong* when a library law takes its place unflagged; a grasp (a payload picked up during the
log) is *right* when the answer reports the change within 1 s with a payload and keeps the untouched copy's effects.

The answer is read through the result types (:mod:`franka_vs_gym.validation.results`) only, so hand-made objects
with the same fields (``selection``, ``ambiguous``, ``unexplained``, ``changes``, ``noise_floor``) are scored the same.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["RIGHT", "AMBIGUOUS", "CONFIDENT_WRONG", "FLAGGED", "MISSED", "OUTCOMES", "MAX_CANDIDATES", "ACCEPT",
           "SHARED", "canon", "named", "flagged_joints", "score_case"]

RIGHT, AMBIGUOUS, CONFIDENT_WRONG, FLAGGED, MISSED = "right", "ambiguous", "confident wrong", "flagged", "missed"
OUTCOMES = (RIGHT, AMBIGUOUS, CONFIDENT_WRONG, FLAGGED, MISSED)
#: an ambiguity counts as "cannot tell apart" for at most this many candidates
MAX_CANDIDATES = 3
#: a new unexplained finding flags a joint when it removes this many noise floors more than the untouched one's
FLAG_MARGIN = 0.25
STEP = {"coulomb_friction", "sigmoid_friction", "asymmetric_friction", "stribeck_friction"}
#: injected effect -> the names that count as naming it
ACCEPT = {"payload": {"payload"}, "gravity_tilt": {"gravity_tilt"}, "torque_offset": {"torque_offset"},
          "viscous_friction": {"viscous_friction"}, "coulomb_friction": STEP, "armature": {"armature"},
          "delay": {"delay"}}
#: effects that act on every joint at once (the name counts, on all joints)
SHARED = {"payload", "gravity_tilt", "delay", "link_inertials", "link_mass"}


def canon(name: str) -> str:
    """The step-friction laws (Coulomb, sigmoid, asymmetric, Stribeck) are one family: a change among them on a joint
    is not a new name."""
    return "step_friction" if name in STEP else name


def named(d: Any, raw: bool = False) -> dict[str, set[int]]:
    """Effect name (its family unless ``raw``) -> the joints it is named on (a shared effect: every joint)."""
    out: dict[str, set[int]] = {}
    for s in d.selection:
        n = s.effect if raw else canon(s.effect)
        out.setdefault(n, set()).update(set(range(7)) if s.effect in SHARED else set(map(int, s.joints)))
    return out


def _params(d: Any, name: str) -> dict[str, Any] | None:
    return next((s.params for s in d.selection if s.effect == name), None)


def _findings(d: Any) -> dict[int, float]:
    out: dict[int, float] = {}
    if getattr(d, "unexplained", None) is not None:
        for f in d.unexplained.findings:
            out[int(f.joint)] = max(out.get(int(f.joint), 0.0), float(f.removed_rms))
    return out


def flagged_joints(base: Any, d: Any) -> set[int]:
    """Joints the answer newly flags as unexplained: a structure-test finding that removes more than
    :data:`FLAG_MARGIN` noise floors beyond the untouched copy's finding on that joint."""
    fb, fd = _findings(base), _findings(d)
    noise = np.asarray(d.noise_floor, dtype=float)
    return {j for j, r in fd.items() if r > fb.get(j, 0.0) + FLAG_MARGIN * noise[j]}


def _ambiguous_pairs(base: Any, d: Any) -> set[tuple[str, int]]:
    """(name family, joint) pairs the answer lists among at most MAX_CANDIDATES it cannot tell apart."""
    out = set()
    for a in getattr(d, "ambiguous", None) or []:
        if len(a.candidates) <= MAX_CANDIDATES:
            out |= {(canon(c), int(j)) for c in a.candidates for j in (a.joints or range(7))}
    return out


def _hit(t: dict[str, Any], base: Any, d: Any, nd: dict[str, set[int]], nb: dict[str, set[int]]) -> bool:
    """Is the injected library effect ``t`` named on its joints (a shared effect: with the right size)?"""
    acc = {canon(a) for a in ACCEPT[t["effect"]]}
    if t["effect"] not in SHARED:
        return all(any(j in nd.get(a, set()) for a in acc) for j in t["joints"])
    if not acc & set(nd):
        return False
    if t["effect"] == "gravity_tilt" and "gravity_tilt" in nb:  # already named untouched: its change must match
        dg = np.subtract(_params(d, "gravity_tilt")["delta_gravity_m_per_s2"],
                         _params(base, "gravity_tilt")["delta_gravity_m_per_s2"])
        want = np.asarray(t["delta_gravity_m_per_s2"], dtype=float)
        return bool(np.linalg.norm(dg - want) < 0.5 * np.linalg.norm(want))
    if t["effect"] == "payload":
        m = (_params(d, "payload") or {}).get("mass_kg", 0.0) - (_params(base, "payload") or {}).get("mass_kg", 0.0)
        return bool(abs(m - t["mass_kg"]) < 0.5 * t["mass_kg"])
    return True


def score_case(base: Any, d: Any, truth: list[dict[str, Any]]) -> dict[str, Any]:
    """Score the answer ``d`` on an injected copy against the untouched copy's answer ``base`` at the same rate;
    ``truth``: the injected effects (``effect``, ``joints`` and their parameters, as :func:`injected.inject` returns
    them). Returns ``outcome`` (one of :data:`OUTCOMES`) and what it rests on."""
    nb, nd = named(base), named(d)
    touched = set().union(*[set(t["joints"]) for t in truth]) or set(range(7))
    lib = [t for t in truth if t["effect"] in ACCEPT]
    outside = [t for t in truth if t["effect"] not in ACCEPT]
    changes = list(getattr(d, "changes", None) or [])
    grasp = next((t for t in outside if t["effect"] == "grasp"), None)
    accepted: dict[int, set[str]] = {j: set() for j in range(7)}  # name families accepted on each joint
    for t in lib:
        for j in (range(7) if t["effect"] in SHARED else t["joints"]):
            accepted[j] |= {canon(a) for a in ACCEPT[t["effect"]]}
    if grasp is not None and changes:  # a payload that changes during the log: the payload is its name
        for j in range(7):
            accepted[j].add("payload")
    new = {(n, j) for n, js in nd.items() for j in js if j not in nb.get(n, set())}
    gone = {(n, j) for n, js in nb.items() for j in js if j not in nd.get(n, set())}
    wrong = {(n, j) for n, j in new if n not in accepted[j]}
    flags = flagged_joints(base, d)
    amb = _ambiguous_pairs(base, d)
    confident = {(n, j) for n, j in wrong if j not in flags and (n, j) not in amb}
    rb, rd = named(base, raw=True), named(d, raw=True)
    raw_changed = ({(n, j) for n, js in rd.items() for j in js if j not in rb.get(n, set())}
                   | {(n, j) for n, js in rb.items() for j in js if j not in rd.get(n, set())})
    res: dict[str, Any] = {
        "named": {n: sorted(js) for n, js in nd.items()}, "new": sorted(map(list, new)),
        "gone": sorted(map(list, gone)),
        "confident_wrong_names": sorted(map(list, confident)), "flagged_joints": sorted(flags),
        "others_changed": any(n not in SHARED and j not in touched for n, j in raw_changed),
        "ambiguous": [[list(a.candidates), list(map(int, a.joints))] for a in getattr(d, "ambiguous", None) or []],
        "changes": [{"t": float(c.t), "what": c.what} for c in changes], "explained": bool(d.explained)}
    if confident:
        res["outcome"] = CONFIDENT_WRONG
    elif outside:
        if grasp is not None and changes:
            t_ok = any(abs(c.t - grasp["t_s"]) < 1.0 and "payload" in c.what for c in changes)
            kept = set(nb) - {"payload", "link_inertials"} <= set(nd)  # the effects present all along
            res["outcome"] = RIGHT if t_ok and kept and not wrong else FLAGGED
        elif flags & touched or any(j in touched for _, j in amb):
            res["outcome"] = FLAGGED
        else:
            res["outcome"] = MISSED
    else:
        hits = [_hit(t, base, d, nd, nb) for t in lib]
        told = [h or any((canon(a), j) in amb for a in ACCEPT[t["effect"]]
                         for j in (touched if t["effect"] in SHARED else t["joints"]))
                for h, t in zip(hits, lib, strict=True)]
        if all(hits) and not wrong:
            res["outcome"] = RIGHT
        elif all(told) and (not all(hits) or wrong <= amb):
            res["outcome"] = AMBIGUOUS
        elif flags & (touched | {j for _, j in wrong}):
            res["outcome"] = FLAGGED
        else:
            res["outcome"] = MISSED
    return res
