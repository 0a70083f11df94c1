"""The run as an MCAP log: measurement, model prediction, residual, each effect's torque and the findings on one
timeline, for the viewers robotics people already use (Foxglove, PlotJuggler).

Written with Foxglove's SDK (``foxglove-sdk``: its MCAP writer is compiled, so the per-message cost of a 1 kHz log's
120 000-150 000 messages is about a microsecond each, a quarter of the pure-Python ``mcap`` writer's; zstd-compressed
chunks), in a context of its own per file (nothing is logged anywhere else). Messages are JSON with a JSON schema
per channel, so both viewers plot the fields (e.g. ``/residual.after[3]``) without message definitions; the
messages of all channels are written in time order. Channels:

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

import contextlib
import errno
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym.validation.report.content import timeline

_VEC7 = {"type": "array", "items": {"type": ["number", "null"]}, "minItems": 7, "maxItems": 7}


def _schema(title: str, fields: dict[str, str]) -> bytes:
    props = {k: {**_VEC7, "description": d} for k, d in fields.items()}
    return json.dumps({"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title, "type": "object",
                       "properties": props, "required": list(fields)}).encode()


def _rows(arrays: dict[str, np.ndarray], n: int, constant: dict[str, np.ndarray] | None = None) -> list[bytes]:
    """One JSON message per sample; numbers with 6 significant digits, NaN as null. ``constant`` fields (the same
    in every message, e.g. the noise floor) are formatted once. The whole table is formatted in one operation."""
    keys = list(arrays)
    cols = [np.asarray(arrays[k], float)[:n].reshape(n, -1) for k in keys]
    parts = [f'"{k}":[' + ",".join(["%.6g"] * c.shape[1]) + "]" for k, c in zip(keys, cols, strict=True)]
    for k, v in (constant or {}).items():
        parts.append(f'"{k}":[' + ",".join(format(float(x), ".6g") for x in np.ravel(v)).replace("%", "%%") + "]")
    fmt = "{" + ",".join(parts) + "}\n"
    text = (fmt * n) % tuple(np.hstack(cols).ravel().tolist()) if cols else fmt * n
    if "n" in text.replace("null", ""):  # nan, inf: not JSON
        text = text.replace("-inf", "null").replace("inf", "null").replace("nan", "null")
    return text.encode().split(b"\n")[:-1]


def write_mcap(path: str | Path, res, diagnosis=None, fit=None, summary: dict[str, Any] | None = None) -> Path:
    """Write the run (a CompareResult and, when given, the Diagnosis or FitResult of the same log) to ``path``.
    ``summary`` is the JSON-able summary for ``/findings`` (default: the diagnosis' or fit's ``to_dict()``)."""
    import foxglove
    from foxglove.mcap import MCAPCompression, MCAPWriteOptions

    tl = timeline(res, diagnosis, fit)
    if summary is None:
        obj = diagnosis if diagnosis is not None else fit
        summary = obj.to_dict() if obj is not None else res.to_dict()
    p = Path(path)
    t_ns = np.round((tl.t0_abs + tl.time) * 1e9).astype(np.int64)
    t_start = int(t_ns[0])
    n = len(tl.time)
    streams: list[tuple[str, str, dict[str, str], np.ndarray, list[bytes]]] = []  # topic, title, fields, t, msgs
    streams.append(("/measured", "franka_vs.Measured", {"q": "rad", "dq": "rad/s, filtered",
                                                        "ddq": "rad/s^2, filtered", "tau_J": "Nm, as measured"},
                    t_ns, _rows({"q": tl.q, "dq": tl.dq, "ddq": res.data.ddq, "tau_J": tl.tau}, n)))
    model = {"tau_before": tl.model_before}
    resid = {"before": tl.residual_before}
    if tl.model_after is not None:
        model["tau_after"] = tl.model_after
        resid["after"] = tl.residual_after
    streams.append(("/model", "franka_vs.Model", {k: "Nm, inverse dynamics on the measured motion" for k in model},
                    t_ns, _rows(model, n)))
    streams.append(("/residual", "franka_vs.Residual", {k: "Nm" for k in [*resid, "noise_floor"]}, t_ns,
                    _rows(resid, n, constant={"noise_floor": tl.noise})))
    if tl.contributions:
        tc = tl.contribution_time if tl.contribution_time is not None else tl.time
        tc_ns = np.round((tl.t0_abs + np.asarray(tc)) * 1e9).astype(np.int64)
        for name, c in tl.contributions.items():
            c = np.asarray(c, float)
            if c.ndim == 2 and len(c) == len(tc):
                streams.append((f"/effects/{name}", "franka_vs.EffectTorque", {"tau": f"Nm added by {name}"}, tc_ns,
                                _rows({"tau": c}, len(c))))
    if tl.replay_q is not None:
        streams.append(("/replay", "franka_vs.Replay", {"q": "rad, simulated", "tau_J": "Nm, simulated"}, t_ns,
                        _rows({"q": tl.replay_q, "tau_J": tl.replay_tau}, n)))
    findings = json.dumps({"$schema": "https://json-schema.org/draft/2020-12/schema", "title": "franka_vs.Findings",
                           "type": "object",
                           "description": "the run's summary: verdict, selected effects, parameters, findings"})
    streams.append(("/findings", "franka_vs.Findings", {}, np.array([t_start], np.int64),
                    [json.dumps(summary, default=_jsonable).encode()]))

    ctx = foxglove.Context()  # this file's own: channels of other writers (or a live server) see nothing
    sink = _Sink(open(p, "wb"), p)  # noqa: SIM115 - closed below, after the writer
    writer = foxglove.open_mcap(sink, context=ctx, writer_options=MCAPWriteOptions(
        compression=MCAPCompression.Zstd, profile="", chunk_size=4 << 20))
    try:
        channels = []
        for topic, title, fields, _, _ in streams:
            data = findings.encode() if title == "franka_vs.Findings" else _schema(title, fields)
            channels.append(foxglove.Channel(topic, schema=foxglove.Schema(name=title, encoding="jsonschema",
                                                                           data=data),
                                             message_encoding="json", context=ctx))
        # every channel's messages in one time order (stable: at equal times, the channels' order above)
        times = np.concatenate([s[3] for s in streams])
        which = np.concatenate([np.full(len(s[3]), k, np.int32) for k, s in enumerate(streams)])
        index = np.concatenate([np.arange(len(s[3])) for s in streams])
        order = np.argsort(times, kind="stable")
        logs = [c.log for c in channels]
        msgs = [s[4] for s in streams]
        for t, k, i in zip(times[order].tolist(), which[order].tolist(), index[order].tolist(), strict=True):
            logs[k](msgs[k][i], log_time=t)
        meta = {"source": str(res.data.log.source or ""), "kind": "fit" if fit is not None else
                ("diagnosis" if diagnosis is not None else "comparison")}
        if diagnosis is not None:
            meta["verdict"] = str(diagnosis.verdict)
            meta["selected"] = ",".join(diagnosis.selected)
        if fit is not None:
            meta["effects"] = ",".join(fit.effects)
        writer.write_metadata("franka_vs", meta)
        writer.close()
    except RuntimeError as e:  # the MCAP library reports a failed write as a RuntimeError
        with contextlib.suppress(RuntimeError):
            writer.close()  # refuses once a write failed: the staged file is removed by the caller
        sink.close()
        raise sink.error or _write_error(p, e) from None
    except BaseException:
        with contextlib.suppress(RuntimeError):
            writer.close()
        sink.close()
        raise
    sink.close()
    if sink.error is not None:  # e.g. ENOSPC: the file is incomplete; said once, by its path
        raise sink.error
    return p


class _Sink:
    """The MCAP file as the writer sees it: the first OSError of a write (a full disk, a quota) is kept and from
    then on the writer writes into nothing (its position kept as if the bytes had gone out), so that it finishes
    without printing an error per message; the error is raised, with the file's path, once the writer is closed."""

    def __init__(self, fh: Any, path: Path) -> None:
        self.fh, self.path, self.error = fh, path, None
        self.pos = self.size = 0

    def _fail(self, e: OSError) -> None:
        if self.error is None:
            self.error = OSError(e.errno, e.strerror or str(e), str(self.path))

    def write(self, b: Any) -> int:
        n = len(memoryview(b).cast("B"))
        if self.error is None:
            try:
                self.fh.write(b)
            except OSError as e:
                self._fail(e)
        self.pos += n
        self.size = max(self.size, self.pos)
        return n

    def seek(self, offset: int, whence: int = 0) -> int:
        self.pos = offset if whence == 0 else self.pos + offset if whence == 1 else self.size + offset
        if self.error is None:
            try:
                self.fh.seek(self.pos)
            except OSError as e:
                self._fail(e)
        return self.pos

    def tell(self) -> int:
        return self.pos

    def flush(self) -> None:
        if self.error is None:
            try:
                self.fh.flush()
            except OSError as e:
                self._fail(e)

    def close(self) -> None:
        try:
            self.flush()
            if self.error is None:
                os.fsync(self.fh.fileno())
        except OSError as e:
            self._fail(e)
        finally:
            with contextlib.suppress(OSError):
                self.fh.close()


def _write_error(p: Path, e: RuntimeError) -> OSError:
    """The OSError a failed MCAP write stands for: ENOSPC when the target's file system has (almost) no room left,
    else EIO with the library's message."""
    try:
        st = os.statvfs(p.parent)
        full = st.f_bavail * st.f_frsize < (1 << 20)
    except OSError:
        full = False
    if full:
        return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(p))
    return OSError(errno.EIO, f"writing the MCAP log failed: {' '.join(str(e).split())}", str(p))


def _jsonable(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    return str(o)


__all__ = ["write_mcap"]
