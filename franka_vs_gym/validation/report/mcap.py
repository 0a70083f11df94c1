"""The run as an MCAP log: measurement, model prediction, residual, each effect's torque and the findings on one
timeline, for the viewers robotics people already use (Foxglove, PlotJuggler).

Written with the ``mcap`` package (the format's reference Python reader/writer: pure Python plus its compression
codecs, no robotics middleware needed); messages are JSON with a JSON schema per channel, so both viewers plot the
fields (e.g. ``/residual.after[3]``) without message definitions. Channels:

==========================  ============================================================================
``/measured``               q (rad), dq (rad/s), ddq (rad/s^2) filtered, tau_J (Nm) as measured, per sample
``/model``                  tau_before, tau_after (Nm): the model's inverse dynamics before and after
``/residual``               before, after (Nm) = tau_J - model; noise_floor (Nm)
``/effects/<name>``         tau (Nm): the torque each selected or fitted effect adds
``/replay``                 q, tau_J (rad, Nm): the simulated replay (compare)
``/findings``               one message at the start: verdict, selected effects with parameters, explained,
                            findings and their description (the JSON the command prints)
==========================  ============================================================================

Times are the log's own clock when it has one (seconds since 1970), else seconds from its first sample. The
run's summary is also an MCAP metadata record named ``franka_vs``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym.validation.report.content import timeline

_VEC7 = {"type": "array", "items": {"type": ["number", "null"]}, "minItems": 7, "maxItems": 7}


def _schema(title: str, fields: dict[str, str]) -> bytes:
    props = {k: {**_VEC7, "description": d} for k, d in fields.items()}
    return json.dumps({"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title, "type": "object",
                       "properties": props, "required": list(fields)}).encode()


def _rows(arrays: dict[str, np.ndarray], n: int) -> list[bytes]:
    """One JSON message per sample; numbers with 6 significant digits, NaN as null."""
    keys = list(arrays)
    cols = [np.asarray(arrays[k], float)[:n].reshape(n, -1) for k in keys]
    fmt = "{" + ",".join(f'"{k}":[' + ",".join(["%.6g"] * c.shape[1]) + "]" for k, c in zip(keys, cols,
                                                                                           strict=True)) + "}"
    table = np.hstack(cols).tolist()
    text = "\n".join([fmt % tuple(r) for r in table])
    if "n" in text.replace("null", ""):  # nan, inf: not JSON
        text = text.replace("-inf", "null").replace("inf", "null").replace("nan", "null")
    return [line.encode() for line in text.split("\n")]


def write_mcap(path: str | Path, res, diagnosis=None, fit=None, summary: dict[str, Any] | None = None) -> Path:
    """Write the run (a CompareResult and, when given, the Diagnosis or FitResult of the same log) to ``path``.
    ``summary`` is the JSON-able summary for ``/findings`` (default: the diagnosis' or fit's ``to_dict()``)."""
    from mcap.writer import CompressionType, Writer

    tl = timeline(res, diagnosis, fit)
    if summary is None:
        obj = diagnosis if diagnosis is not None else fit
        summary = obj.to_dict() if obj is not None else res.to_dict()
    p = Path(path)
    t_ns = np.round((tl.t0_abs + tl.time) * 1e9).astype(np.int64)
    t_start = int(t_ns[0])
    with open(p, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD)
        w.start(profile="", library="franka_vs_gym")

        def channel(topic: str, title: str, fields: dict[str, str]) -> int:
            sid = w.register_schema(name=title, encoding="jsonschema", data=_schema(title, fields))
            return w.register_channel(topic=topic, message_encoding="json", schema_id=sid)

        def put(cid: int, times: np.ndarray, msgs: list[bytes]) -> None:
            for seq, (t, m) in enumerate(zip(times, msgs, strict=False)):
                w.add_message(channel_id=cid, log_time=int(t), publish_time=int(t), data=m, sequence=seq)

        n = len(tl.time)
        cid = channel("/measured", "franka_vs.Measured", {"q": "rad", "dq": "rad/s, filtered",
                                                         "ddq": "rad/s^2, filtered", "tau_J": "Nm, as measured"})
        put(cid, t_ns, _rows({"q": tl.q, "dq": tl.dq, "ddq": res.data.ddq, "tau_J": tl.tau}, n))
        model = {"tau_before": tl.model_before}
        resid = {"before": tl.residual_before, "noise_floor": np.broadcast_to(tl.noise, (n, 7))}
        if tl.model_after is not None:
            model["tau_after"] = tl.model_after
            resid["after"] = tl.residual_after
        cid = channel("/model", "franka_vs.Model", {k: "Nm, inverse dynamics on the measured motion" for k in model})
        put(cid, t_ns, _rows(model, n))
        cid = channel("/residual", "franka_vs.Residual", {k: "Nm" for k in resid})
        put(cid, t_ns, _rows(resid, n))
        if tl.contributions:
            tc = tl.contribution_time if tl.contribution_time is not None else tl.time
            tc_ns = np.round((tl.t0_abs + np.asarray(tc)) * 1e9).astype(np.int64)
            for name, c in tl.contributions.items():
                c = np.asarray(c, float)
                if c.ndim == 2 and len(c) == len(tc):
                    cid = channel(f"/effects/{name}", "franka_vs.EffectTorque",
                                  {"tau": f"Nm added by {name}"})
                    put(cid, tc_ns, _rows({"tau": c}, len(c)))
        if tl.replay_q is not None:
            cid = channel("/replay", "franka_vs.Replay", {"q": "rad, simulated", "tau_J": "Nm, simulated"})
            put(cid, t_ns, _rows({"q": tl.replay_q, "tau_J": tl.replay_tau}, n))
        sid = w.register_schema(name="franka_vs.Findings", encoding="jsonschema", data=json.dumps(
            {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": "franka_vs.Findings",
             "type": "object", "description": "the run's summary: verdict, selected effects, parameters, findings"}
        ).encode())
        cid = w.register_channel(topic="/findings", message_encoding="json", schema_id=sid)
        w.add_message(channel_id=cid, log_time=t_start, publish_time=t_start,
                      data=json.dumps(summary, default=_jsonable).encode(), sequence=0)
        meta = {"source": str(res.data.log.source or ""), "kind": "fit" if fit is not None else
                ("diagnosis" if diagnosis is not None else "comparison")}
        if diagnosis is not None:
            meta["verdict"] = str(diagnosis.verdict)
            meta["selected"] = ",".join(diagnosis.selected)
        if fit is not None:
            meta["effects"] = ",".join(fit.effects)
        w.add_metadata("franka_vs", meta)
        w.finish()
    return p


def _jsonable(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    return str(o)


__all__ = ["write_mcap"]
