"""libfranka's ``logToCSV`` files: recognising their header and naming their columns."""

from __future__ import annotations


def is_libfranka_csv(header: list[str]) -> bool:
    """A header written by libfranka's logToCSV (``state.q[0]`` columns)."""
    return any(h.strip().startswith("state.q[") for h in header)


def libfranka_columns(header: list[str]) -> tuple[list[str], float]:
    """Column names of a logToCSV header renamed to the log format, and the factor converting its time to s."""
    names = []
    for h in header:
        h = h.strip()
        if h.startswith("state."):
            names.append(h[len("state."):])
        elif h.startswith("cmd.tau_J_d"):
            names.append(h[len("cmd."):])
        elif h.startswith("cmd."):
            names.append("cmd_" + h[len("cmd."):].replace("[", "_").replace("]", ""))
        else:
            names.append(h)
    return names, 1e-3


