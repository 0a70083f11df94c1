#!/usr/bin/env python
"""Write docs/results.md, and the results table of README.md, from the figure files in docs/results/.

Every measured figure the project quotes lives in one JSON file per study under ``docs/results/`` (the command
that produced it, when, on what, its table and its sentences). This script assembles them: ``docs/results.md``
(every figure, grouped by area) and the README's one results table (each study's ``headline``, between the
``<!-- results-table: begin -->`` and ``<!-- results-table: end -->`` markers). Nothing else writes either.
``tests/test_docs.py`` checks that both equal what this script writes, so an edit by hand fails CI.

    python scripts/results_table.py            # rewrite docs/results.md and the README's table
    python scripts/results_table.py --check    # exit 1 (naming the file) when either is out of date

Adding or updating a figure
---------------------------
1. Edit the study's file in ``docs/results/`` (or add ``docs/results/<slug>.json`` for a new study), e.g.::

       {
        "title": "Replay throughput",                        # the heading in docs/results.md
        "area": "Speed",                                      # one of AREAS below (the section it goes in)
        "order": 160,                                         # position within all files (gaps of 10)
        "command": "python scripts/bench.py --only replay",   # what a reader runs to reproduce it
        "date": "2026-12-04",                                 # when it was measured
        "provenance": "2 cores, load 1.5",                    # optional: machine, load, seeds, commit
        "text": ["A sentence or two of Markdown,", "one list item per source line."],   # optional
        "table": {"columns": ["what", "measured"], "rows": [["steps/s", "12 000"]]},    # optional
        "after": ["Markdown after the table."],                # optional
        "image": {"path": "images/x.png", "alt": "..."},      # optional, relative to docs/
        "headline": {"what": "Replay throughput", "figure": "12 000 steps/s"}           # optional: a README row
       }

   (no comments in the real file: it is plain JSON). Links inside ``text``/``after`` are relative to ``docs/``.
2. When the figure replaces an older one, add a dated line to ``CHANGELOG.md`` saying what it was and why it
   changed (docs/results.md holds only the current figures).
3. Run ``python scripts/results_table.py`` and commit the JSON, docs/results.md and README.md together.

A file with a missing or unknown key, or an area not in AREAS, is refused with one line naming the file and the
key (exit status 2); nothing is written then.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "docs" / "results"
RESULTS_MD = ROOT / "docs" / "results.md"
README = ROOT / "README.md"

AREAS = ["Robot and model", "Visual servoing", "Reinforcement learning", "Torque control",
         "libfranka on the simulator", "Workbench", "Speed"]
REQUIRED = {"title", "area", "order", "command", "date"}
OPTIONAL = {"provenance", "text", "table", "after", "image", "headline"}
BEGIN = "<!-- results-table: begin (written by scripts/results_table.py from docs/results/*.json; do not edit) -->"
END = "<!-- results-table: end -->"


class FigureError(ValueError):
    """A figure file that cannot be assembled; the message names the file and the problem."""


def slug(heading: str) -> str:
    """The anchor GitHub gives a Markdown heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def _lines(value, where: str) -> list[str]:
    if isinstance(value, str):
        return value.split("\n")
    if isinstance(value, list) and all(isinstance(x, str) for x in value):
        return value
    raise FigureError(f"{where}: must be a string or a list of strings")


def load(data_dir: Path = DATA) -> list[dict]:
    """Every figure file, checked and sorted by ``order`` (then file name)."""
    figures = []
    for path in sorted(data_dir.glob("*.json")):
        name = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
        try:
            fig = json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise FigureError(f"{name}: not valid JSON ({e})") from None
        if not isinstance(fig, dict):
            raise FigureError(f"{name}: must hold one JSON object")
        missing, unknown = REQUIRED - set(fig), set(fig) - REQUIRED - OPTIONAL
        if missing:
            raise FigureError(f"{name}: missing key(s) {', '.join(sorted(missing))}")
        if unknown:
            raise FigureError(f"{name}: unknown key(s) {', '.join(sorted(unknown))} "
                              f"(allowed: {', '.join(sorted(REQUIRED | OPTIONAL))})")
        if fig["area"] not in AREAS:
            raise FigureError(f"{name}: area {fig['area']!r} is not one of {AREAS}")
        if slug(fig["title"]) in {slug(a) for a in AREAS}:
            raise FigureError(f"{name}: title {fig['title']!r} repeats an area's heading (links would clash)")
        if not isinstance(fig["order"], (int, float)):
            raise FigureError(f"{name}: order must be a number")
        table = fig.get("table")
        if table is not None:
            cols, rows = table.get("columns"), table.get("rows")
            if not isinstance(cols, list) or not isinstance(rows, list) or set(table) - {"columns", "rows"}:
                raise FigureError(f"{name}: table must be {{\"columns\": [...], \"rows\": [[...], ...]}}")
            for i, row in enumerate(rows):
                if not isinstance(row, list) or len(row) != len(cols):
                    raise FigureError(f"{name}: table row {i} has {len(row) if isinstance(row, list) else '?'} "
                                      f"cells for {len(cols)} columns")
        head = fig.get("headline")
        if head is not None and (not isinstance(head, dict) or set(head) != {"what", "figure"}):
            raise FigureError(f"{name}: headline must be {{\"what\": ..., \"figure\": ...}}")
        for key in ("text", "after"):
            if key in fig:
                fig[key] = _lines(fig[key], f"{name}: {key}")
        fig["_file"] = str(name)
        figures.append(fig)
    if not figures:
        raise FigureError(f"no figure files in {data_dir}")
    figures.sort(key=lambda f: (f["order"], f["_file"]))
    titles = [f["title"] for f in figures]
    dup = sorted({t for t in titles if titles.count(t) > 1})
    if dup:
        raise FigureError(f"two figure files share the title(s) {dup}: headings and links would clash")
    return figures


def _table(table: dict) -> list[str]:
    cols = table["columns"]
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in table["rows"]]
    return out


def results_md(figures: list[dict]) -> str:
    """docs/results.md: every figure, by area, each with its command, date and provenance."""
    out = ["# Results", "",
           "Every figure the project quotes, each with the command that reproduces it and when it was measured "
           "(on the", "2-core development machine unless said). This page is written by `python "
           "scripts/results_table.py` from", "the files in `docs/results/` (one per study; the script's docstring "
           "says how to add one); how a figure", "changed over time is in the [CHANGELOG](../CHANGELOG.md).", ""]
    for area in AREAS:
        figs = [f for f in figures if f["area"] == area]
        if not figs:
            continue
        out += [f"- {area}: " + ", ".join(f"[{f['title']}](#{slug(f['title'])})" for f in figs)]
    out.append("")
    for area in AREAS:
        figs = [f for f in figures if f["area"] == area]
        if not figs:
            continue
        out += [f"## {area}", ""]
        for f in figs:
            out += [f"### {f['title']}", ""]
            meta = f"`{f['command']}`, {f['date']}"
            if f.get("provenance"):
                meta += f"; {f['provenance']}"
            out += [f"*Measured by* {meta}.", ""]
            if f.get("text"):
                out += f["text"] + [""]
            if f.get("table"):
                out += _table(f["table"]) + [""]
            if f.get("after"):
                out += f["after"] + [""]
            if f.get("image"):
                out += [f"![{f['image']['alt']}]({f['image']['path']})", ""]
    return "\n".join(out).rstrip("\n") + "\n"


def readme_table(figures: list[dict]) -> str:
    """The README's results table: one row per figure file with a headline, linked to its section."""
    rows = ["| what | measured | how, when |", "|---|---|---|"]
    for f in figures:
        if f.get("headline"):
            h = f["headline"]
            rows.append(f"| {h['what']} | {h['figure']} | [{f['date']}]"
                        f"(docs/results.md#{slug(f['title'])}) |")
    return "\n".join([BEGIN, *rows, END])


def readme_with_table(readme: str, figures: list[dict]) -> str:
    start, end = readme.find(BEGIN), readme.find(END)
    if start < 0 or end < start:
        raise FigureError(f"README.md: the markers {BEGIN!r} ... {END!r} are missing")
    return readme[:start] + readme_table(figures) + readme[end + len(END):]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="only compare; exit 1 when a file is out of date")
    args = ap.parse_args(argv)
    try:
        figures = load()
        want = {RESULTS_MD: results_md(figures), README: readme_with_table(README.read_text(), figures)}
    except FigureError as e:
        print(f"results_table: {e}", file=sys.stderr)
        return 2
    stale = [p for p, text in want.items() if not p.exists() or p.read_text() != text]
    if args.check:
        for p in stale:
            print(f"results_table: {p.relative_to(ROOT)} is out of date: run python scripts/results_table.py",
                  file=sys.stderr)
        return 1 if stale else 0
    for p in stale:
        tmp = p.with_name(p.name + ".tmp")
        tmp.write_text(want[p])
        tmp.replace(p)
        print(f"wrote {p.relative_to(ROOT)}", file=sys.stderr)
    if not stale:
        print("docs/results.md and the README's table are up to date", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
