"""Reading a measurement log from a file, a folder or a ROS bag: :func:`load_log` detects the format from the
content and hands it to its reader (the workbench's own CSV/NPZ and the Gaz et al. 2019 text folder here; libfranka's
logToCSV, ROS bags and dumps of pylibfranka/franky robot states in :mod:`franka_vs_gym.validation.readers`); the
formats are described in :mod:`franka_vs_gym.validation.logs`."""

from __future__ import annotations

import csv
import json
import os
import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym import io
from franka_vs_gym.validation.logs import (
    _COL,
    GAZ_FILES,
    JOINT_FIELDS,
    MAX_STEP_S,
    REQUIRED,
    MeasurementLog,
    _meta_kwargs,
    _meta_where,
    _read_sidecar,
)


def _columns_to_fields(header: list[str], data: np.ndarray, where: str) -> dict[str, np.ndarray]:
    names = [h.strip() for h in header]
    if "time" not in names:
        raise ValueError(f"{where}: missing column 'time' (s)")
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise ValueError(f"{where}: duplicate columns {dup}")
    groups: dict[str, dict[int, int]] = {}
    for col, name in enumerate(names):
        m = _COL.match(name)
        if m:
            base, idx = m.group(1), int(m.group(2) if m.group(2) is not None else m.group(3))
            prev = groups.setdefault(base, {}).get(idx)
            if prev is not None:  # two spellings of one column (q[0] and q_0): equal values are one column
                if not np.array_equal(data[:, prev], data[:, col], equal_nan=True):
                    r = int(np.argmax(data[:, prev] != data[:, col]))
                    raise ValueError(f"{where}: columns {names[prev]!r} and {name!r} are the same column written "
                                     f"twice with different values (first at data row {r}: {data[r, prev]:g} vs "
                                     f"{data[r, col]:g}); keep one")
                continue
            groups[base][idx] = col
    out = {"time": data[:, names.index("time")]}
    for f in JOINT_FIELDS:
        g = groups.get(f)
        if g is None:
            if f in REQUIRED:
                raise ValueError(f"{where}: missing columns {f}[0]..{f}[6] ({f!r} is required)")
            continue
        idx = sorted(g)
        if idx != list(range(7)):
            missing = [f"{f}[{i}]" for i in range(7) if i not in g]
            extra = [f"{f}[{i}]" for i in idx if i >= 7]
            msg = f"{where}: {f} has joints {idx}; the FER has 7 joints (indices 0..6)"
            if missing:
                msg += f"; missing {missing}"
            if extra:
                msg += f"; unexpected {extra}"
            raise ValueError(msg)
        out[f] = data[:, [g[i] for i in range(7)]]
    return out


_LOADTXT_ROW = re.compile(r"at row (\d+)")
_LOADTXT_COLS = re.compile(r"number of columns changed from (\d+) to (\d+) at row (\d+)")
_LOADTXT_BAD = re.compile(r"could not convert string '(.*)' to float64 at row (\d+), column (\d+)")


def _load_csv(path: Path) -> dict[str, np.ndarray]:
    """Header with csv, values with numpy's C parser, straight into one float64 array (no per-value Python
    objects: a 200 MB log needs about its array's size in memory)."""
    with io.open_input(path, "r", what="log", newline="") as fh:
        first = fh.readline()
        if not first.strip():
            raise ValueError(f"{path}: empty file" if not first else f"{path}: the first line must be a header")
        header = next(csv.reader([first]))
        if all(_isfloat(h) for h in header):
            raise ValueError(f"{path}: the first line must be a header with column names (time, q[0], ...)")
        delimiter = "," if len(header) > 1 or "," in first else None
        try:
            with warnings.catch_warnings():  # "input contained no data": said below as "no data rows"
                warnings.simplefilter("ignore", UserWarning)
                data = np.loadtxt(fh, dtype=np.float64, delimiter=delimiter, ndmin=2, comments=None, encoding=None)
        except ValueError as e:
            msg = " ".join(str(e).split())
            m = _LOADTXT_BAD.search(msg)
            if m:  # numpy counts data rows from 0 and columns from 1; the file's lines start at 1 with the header
                col = int(m.group(3)) - 1
                msg = (f"line {int(m.group(2)) + 2}: {m.group(1)!r} is not a number (column "
                       f"{header[col].strip() if 0 <= col < len(header) else m.group(3)})")
            elif (m := _LOADTXT_COLS.search(msg)) is not None:  # here numpy counts data rows from 1
                msg = (f"line {int(m.group(3)) + 1} has {m.group(2)} values, the header has {len(header)} "
                       "columns")
            elif (m := _LOADTXT_ROW.search(msg)) is not None:
                msg = _LOADTXT_ROW.sub(f"at line {int(m.group(1)) + 2}", msg)
            raise ValueError(f"{path}: {msg}") from None
    if data.size == 0:
        raise ValueError(f"{path}: no data rows")
    if data.shape[1] != len(header):
        raise ValueError(f"{path}: rows have {data.shape[1]} values, the header has {len(header)} columns")
    bad = ~np.isfinite(data)
    if bad.any():  # named by its line and column here, where they are known (a NaN, or a huge number: a blob?)
        r, c = (int(x) for x in np.argwhere(bad)[0])
        raise ValueError(f"{path}: {header[c].strip()} contains NaN or inf (first at row {r}, line {r + 2} of the "
                         f"file: {_describe_cell(path, r + 2, c, delimiter)})")
    from franka_vs_gym.validation.readers import is_libfranka_csv, libfranka_columns

    if is_libfranka_csv(header):  # libfranka's logToCSV: state./cmd. prefixes, time in ms
        header, to_s = libfranka_columns(header)
        data[:, [h.strip() for h in header].index("time")] *= to_s
    return _columns_to_fields(header, data, str(path))


def _describe_cell(path: Path, lineno: int, col: int, delimiter: str | None) -> str:
    """What is wrong with the non-finite value at ``lineno`` (1-based, header included), column ``col``: the text of
    the cell read again from the file (a line at a time: a 20 MB field costs 20 MB once)."""
    with io.open_input(path, "r", what="log", newline="") as fh:
        for k, line in enumerate(fh, start=1):
            if k == lineno:
                cells = line.rstrip("\r\n").split(delimiter)
                text = cells[col].strip() if col < len(cells) else ""
                break
        else:
            return "not a finite number"
    if len(text) > 64:
        return f"a value of {len(text)} characters ({text[:16]}...): a blob in the column or a corrupt file?"
    return f"{text!r}"


def _isfloat(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _load_npz(path: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    z = io.load_npz(path, what="log")  # headers checked before reading; uncompressed arrays memory-mapped
    keys = set(z)

    def floats(name: str) -> np.ndarray:
        try:
            return np.array(z[name], dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{path}: array {name!r} is not numeric (dtype {z[name].dtype})") from None

    meta: dict[str, Any] = {}
    if "meta" in keys:
        try:
            meta = io.loads_json(str(np.asarray(z["meta"])), f"{path}: array 'meta'")
        except json.JSONDecodeError as e:
            raise ValueError(f"{path}: array 'meta' is not a JSON string: {e}") from None
        if not isinstance(meta, dict):
            raise ValueError(f"{path}: array 'meta' must hold a JSON object")
    if "time" not in keys:
        raise ValueError(f"{path}: missing array 'time' (s)")
    out = {"time": floats("time").ravel()}
    for f in JOINT_FIELDS:
        if f in keys:
            out[f] = floats(f)
        elif f in REQUIRED:
            # accept per-joint arrays q[0]..q[6] / q_0..q_6 as well
            cols = [next((k for k in (f"{f}[{i}]", f"{f}_{i}") if k in keys), None) for i in range(7)]
            if all(c is not None for c in cols):
                parts = [floats(c) for c in cols]  # type: ignore[arg-type]
                if len({p.shape for p in parts}) != 1 or parts[0].ndim != 1:
                    raise ValueError(f"{path}: per-joint arrays of {f!r} must be 1-D of equal length")
                out[f] = np.stack(parts, axis=1)
            else:
                raise ValueError(f"{path}: missing array {f!r} (shape (N, 7))")
    return out, meta


def _layout_score(x: np.ndarray) -> float:
    """How much (n, 7) samples look like 7 joints sampled in time: the typical difference between neighbouring
    columns (different joints) over the typical step in time (one sample). A misread layout puts consecutive
    samples of one joint side by side (ratio near 1) or interleaves joints along time (large steps)."""
    step = float(np.median(np.abs(np.diff(x, axis=0))))
    across = float(np.median(np.abs(np.diff(x, axis=1))))
    scale = float(np.abs(x).max()) + 1e-300
    return (across + 1e-12 * scale) / (step + 1e-12 * scale)


def _gaz_layout(files: dict[str, np.ndarray], lines: dict[str, list[int]], n: int, folder: Path) -> str:
    """"sample" (7 values per sample, in time order) or "joint" (all n samples of joint 0, then joint 1...) for
    the joint files of a Gaz folder. The line structure decides when it can (n lines of 7 values, or 7 lines of n
    values); otherwise the layout in which the columns look like 7 joints sampled in time wins, judged on the
    positions first (then velocities, torques); a folder where neither layout is clearly better is refused."""
    for f in ("q", "dq", "tau_J"):
        counts = lines[f]
        if len(counts) == n and all(k == 7 for k in counts):
            return "sample"
        if len(counts) == 7 and all(k == n for k in counts) and n != 7:
            return "joint"
    if n < 3:
        return "sample"
    for f in ("q", "dq", "tau_J"):
        v = files[f]
        if not np.isfinite(v).all() or np.ptp(v) == 0:
            continue
        s, j = _layout_score(v.reshape(n, 7)), _layout_score(v.reshape(7, n).T)
        if s >= 3 * j:
            return "sample"
        if j >= 3 * s:
            return "joint"
    raise ValueError(f"{folder}: cannot tell whether the values are sample-major (7 per sample) or joint-major (all "
                     "samples of joint 0 first): neither layout looks like 7 joints sampled in time")


def _read_gaz_file(p: Path) -> tuple[np.ndarray, list[int]]:
    with io.open_input(p, "r", what="Gaz log file") as fh:
        counts: list[int] = []
        chunks: list[np.ndarray] = []
        for lineno, line in enumerate(fh, start=1):
            parts = line.replace(",", " ").split()
            if not parts:
                continue
            try:
                chunks.append(np.array(parts, dtype=np.float64))
            except ValueError:
                bad = next(x for x in parts if not _isfloat(x))
                raise ValueError(f"{p}: line {lineno}: {bad!r} is not a number") from None
            counts.append(len(parts))
    if not chunks:
        raise ValueError(f"{p}: no values")
    return np.concatenate(chunks), counts


def _load_gaz(folder: Path) -> dict[str, np.ndarray]:
    out, lines = {}, {}
    for f, name in GAZ_FILES.items():
        p = folder / name
        if not os.path.lexists(p):
            raise ValueError(f"{folder}: missing file {name} (Gaz et al. 2019 log folder)")
        out[f], lines[f] = _read_gaz_file(p)
    n = len(out["time"])
    for f in ("q", "dq", "tau_J"):
        if out[f].size != 7 * n:
            raise ValueError(f"{folder / GAZ_FILES[f]}: {out[f].size} values for {n} timestamps; expected 7 per "
                             f"sample ({7 * n})")
    layout = _gaz_layout(out, lines, n, folder)
    for f in ("q", "dq", "tau_J"):
        out[f] = out[f].reshape(n, 7) if layout == "sample" else out[f].reshape(7, n).T.copy()
    return out


def _native_header(header: list[str]) -> bool:
    """Our CSV format (``time`` and ``field[i]``/``field_i`` columns of the log's fields only) or logToCSV's."""
    from franka_vs_gym.validation.readers import is_libfranka_csv

    if is_libfranka_csv(header):
        return True
    names = [h.strip() for h in header]
    if "time" not in names:
        return False
    for n in names:
        m = _COL.match(n)
        if n != "time" and not (m and m.group(1) in JOINT_FIELDS):
            return False
    return True


# suffixes under which a text table is expected; other text files (or a binary format we do not read, e.g. Parquet,
# HDF5, MATLAB) are refused by name rather than parsed as a table
_TEXT_SUFFIXES = frozenset({"", ".csv", ".tsv", ".txt", ".dat", ".log"})


def _load_file(p: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Arrays and metadata of a log file; the format is detected from the content (see :func:`load_log`)."""
    from franka_vs_gym.validation.readers import robot_states as rs

    kind = rs.sniff(p)
    suffix = p.suffix.lower()
    if suffix == ".npz" and kind != "npz":
        raise ValueError(f"{p}: not a valid .npz archive (empty, truncated or another format)")
    if kind == "text" and suffix not in _TEXT_SUFFIXES:
        raise ValueError(f"{p}: unknown log format {p.suffix!r} (readable: CSV or other text tables, NPZ, NPY, JSON, "
                         "JSON lines, franky state pickles, ROS 1/ROS 2 bags, Gaz et al. 2019 folders)")
    if kind == "npz":
        z = io.load_npz(p, what="log")
        keys = set(z)
        native = {"time", *REQUIRED} <= keys and z["q"].ndim == 2
        if native:
            t = np.asarray(z["time"], dtype=np.float64).ravel()
            dt = np.diff(t)
            native = not (dt > 0).any() or float(np.median(dt[dt > 0])) < MAX_STEP_S
        return _load_npz(p) if native else rs.read_npz_dump(p)
    if kind == "npy":
        return rs.read_npy(p)
    if kind == "pickle":
        return rs.read_pickle(p)
    if kind == "json":
        return rs.read_json(p)
    with io.open_input(p, "r", what="log", newline="") as fh:
        first = fh.readline()
    if not first.strip():
        raise ValueError(f"{p}: empty file" if not first else f"{p}: the first line must be a header")
    header = next(csv.reader([first]))
    if len(header) == 1 and "," not in first:
        header = first.split()
    if all(_isfloat(h) for h in header):
        raise ValueError(f"{p}: the first line must be a header with column names (time, q[0], ...)")
    if _native_header(header):
        return _load_csv(p), {}
    return rs.read_csv_dump(p, first)


def _with_sidecar(meta: dict[str, Any], side: dict[str, Any]) -> dict[str, Any]:
    """The reader's metadata overridden by the sidecar's; a tool the sidecar declares replaces the one the file
    declared, and so does its stated source."""
    out = dict(meta)
    if "tool" in side:
        out.pop("tool_source", None)
    out.update(side)
    return out


def load_log(path: str | os.PathLike, topic: str | None = None, progress: bool = False,
             tool: str | None = None) -> MeasurementLog:
    """Read a log: a CSV file (ours or libfranka's logToCSV), an NPZ file, a ROS 1 or ROS 2 bag of Franka robot
    states or JointState messages (``topic`` chooses the topic, else it is chosen and the choice stated; see
    :mod:`franka_vs_gym.validation.readers`), a Gaz et al. 2019 text folder (see
    the module docstring), or a dump of pylibfranka/franky robot states (JSON, JSON lines, CSV with flattened or
    whole-list fields, NPZ/NPY, a pickle of franky states; see
    :mod:`franka_vs_gym.validation.readers.robot_states`). The format of a file is detected from its content.

    The sidecar ``<log>.json`` supplies tool, gravity and controller. ``progress`` shows a progress bar on stderr
    while a ROS bag is decoded. ``tool`` ("franka_hand", "none" or "unknown", as ``--tool``) replaces the tool the
    metadata declares, which is then not read (the declared text is kept in ``extra["tool_declared_as"]``). Raises
    FileNotFoundError when the path does
    not exist and ValueError when the content is malformed. The file is only read.
    """
    from franka_vs_gym.validation.readers import is_rosbag, read_rosbag

    p = Path(path)
    if not os.path.lexists(p):
        raise FileNotFoundError(f"log not found: {p}")
    if is_rosbag(p):
        if not p.is_dir():  # a bare .mcap/.db3: a regular file (a FIFO or device would hang the reader)
            io.check_input_file(p, what="ROS bag")
        arrays, meta = read_rosbag(p, topic, progress=progress)
        meta = _with_sidecar(meta, _read_sidecar(p))
    elif p.is_dir():
        arrays = _load_gaz(p)
        meta: dict[str, Any] = {"tool": None, "source_format": "gaz2019"}
        meta.update(_read_sidecar(p / "log"))
    else:
        try:
            arrays, meta = _load_file(p)
        except UnicodeDecodeError as e:  # a binary file of no format we read
            raise ValueError(f"{p}: not a log: byte {e.start} is not UTF-8 text, and the content is no NPZ, NPY, "
                             "pickle of robot states or ROS bag") from None
        except csv.Error as e:  # e.g. "field larger than field limit (131072)": a blob or a corrupt file
            raise ValueError(f"{p}: not a readable table: {e} (a cell of over 128 KiB; a blob in a column or a "
                             "corrupt file?)") from None
        meta = _with_sidecar(meta, _read_sidecar(p))
    if tool is not None:  # --tool: the declaration is overridden, not read (a name it cannot read is no error)
        if "tool" in meta and meta["tool"] not in ("franka_hand", None, "none"):
            meta["tool_declared_as"] = meta["tool"] if isinstance(meta["tool"], str) else "an object"
        meta["tool"] = "franka_hand" if tool == "franka_hand" else None
        meta["tool_source"] = "--tool"
    kw = _meta_kwargs(meta, _meta_where(p))
    t = arrays.pop("time")
    return MeasurementLog(t, **arrays, **kw, source=str(p))


__all__ = ["load_log"]
