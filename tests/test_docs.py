"""Every code block of README.md, CHANGELOG.md and docs/**/*.md runs, as a newcomer would run it; every link
between them resolves; docs/results.md and the README's results table are what scripts/results_table.py writes.

Blocks are fenced with a language: ``python`` blocks run as a script, ``bash`` blocks line by line (``franka-vs``
and ``python`` commands run; a line ending in ``&`` starts a server in the background, read up to its ready line and
stopped when the block ends; ``pip install`` lines are checked against the project's extras, since CI itself runs
the install; a line with ``[--option]`` is a synopsis, whose every option must be in that command's ``--help``);
``json`` blocks must parse; ``text`` blocks are formulas and output, never commands. Each block runs in a fresh
folder next to a link to ``shared/`` (so ``../shared/data/...`` works as in the repository), with links to
``examples/``, ``baselines/``, ``scripts/`` and ``docs/``.

A block states what it needs in an HTML comment on the line before its fence, which a reader of the rendered page
does not see but a reader of the source does:

    <!-- doc-test: fixtures=run.csv,calibrated.json; replace=600000:2048; timeout=300 -->

``ci`` marks the README's test command, which CI runs itself (checked identical to ``.ci/run`` here).
``fixtures`` are made first (see ``FIXTURES``: a short simulated log with a hidden payload, a calibrated-model file,
bags, a client script); ``replace=A:B`` (several: ``A:B|C:D``) runs the block with the text A replaced by B (a
long training run shortened; the substitution is visible in the source next to the block); ``needs=rosbags``
skips where that module is missing; ``data=PATH`` (several: ``A,B``) names files under ``../shared/data`` that a
script reads through its own configuration, so the block skips where they are absent;
``excerpt=FILE`` marks an excerpt of a file of the repository: every code line of the block (comments aside,
``...`` standing for omitted lines) must be a line of that file, and the file itself runs.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
DOCS = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").rglob("*.md"))]
LANGS = {"python", "bash", "json", "text"}
_FENCE = re.compile(r"^```(?P<lang>[\w-]*)[ \t]*\n(?P<code>.*?)^```[ \t]*$", re.S | re.M)
_DIRECTIVE = re.compile(r"<!--\s*doc-test:\s*(?P<body>.*?)\s*-->\s*$")


@dataclass
class Block:
    path: Path
    line: int
    lang: str
    code: str
    opts: dict[str, str] = field(default_factory=dict)

    @property
    def id(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


def _blocks() -> list[Block]:
    out = []
    for path in DOCS:
        text = path.read_text()
        for m in _FENCE.finditer(text):
            line = text.count("\n", 0, m.start()) + 1
            before = text[:m.start()].rstrip("\n").rsplit("\n", 1)[-1]
            opts = {}
            d = _DIRECTIVE.search(before)
            if d:
                for part in d.group("body").split(";"):
                    if part.strip():
                        k, _, v = part.strip().partition("=")
                        opts[k.strip()] = v.strip()
            out.append(Block(path, line, m.group("lang"), m.group("code"), opts))
    return out


BLOCKS = _blocks()
CODE = [b for b in BLOCKS if b.lang in ("python", "bash")]
JSON = [b for b in BLOCKS if b.lang == "json"]


# ----------------------------------------------------------------------------------------------------- fixtures
def _log(dest: Path) -> None:
    """run.csv: 8 s of a simulated FER tracking run whose plant carries a 0.6 kg payload the model is not told of."""
    from franka_vs_gym.validation.hidden import make_hidden_effect_log
    from franka_vs_gym.validation.logs import save_log

    log, _ = make_hidden_effect_log("payload", duration=8.0, seed=3, magnitude=1.0)
    save_log(log, dest)


def _calibrated(dest: Path) -> None:
    """calibrated.json / cal.json: a calibrated-model file as `franka-vs fit` writes it (the shipped FER model with a
    small fitted torque offset)."""
    import numpy as np

    from franka_vs_gym.model import ModelConfig

    ModelConfig(torque_offset=np.array([0.05, -0.08, 0.02, 0.04, 0.0, 0.01, 0.0]),
                notes={"made_by": "tests/test_docs.py fixture"}).save(dest)


def _ros2_bag(dest: Path) -> None:
    """run_bag/: a rosbag2 folder (MCAP) of sensor_msgs/JointState from a simulated run without a tool."""
    sys.path.insert(0, str(ROOT / "tests"))
    import test_validation_bags as tb

    from franka_vs_gym.validation.hidden import make_hidden_effect_log

    log, _ = make_hidden_effect_log("viscous_friction", duration=6.0, seed=4, magnitude=1.0)
    tb._write_ros2(dest, log, "mcap")


def _ros1_bag(dest: Path) -> None:
    """franka_ros_run.bag: a ROS 1 bag of franka_ros FrankaState messages from a simulated run."""
    sys.path.insert(0, str(ROOT / "tests"))
    import test_validation_bags as tb

    from franka_vs_gym.validation.hidden import make_hidden_effect_log

    log, _ = make_hidden_effect_log("viscous_friction", duration=6.0, seed=5, magnitude=1.0)
    tb._write_ros1(dest, log)


def _client(dest: Path) -> None:
    """my_script.py: a pylibfranka client that reads one robot state from the address it is given."""
    dest.write_text("import sys\nimport pylibfranka\n\n"
                    "robot = pylibfranka.Robot(sys.argv[1], pylibfranka.RealtimeConfig.kIgnore)\n"
                    "print(robot.read_once().q)\n")


FIXTURES = {"run.csv": _log, "calibrated.json": _calibrated, "cal.json": _calibrated, "run_bag": _ros2_bag,
            "franka_ros_run.bag": _ros1_bag, "my_script.py": _client}


@pytest.fixture(scope="session")
def made(tmp_path_factory) -> Path:
    """Fixtures made once per test process, copied into each block's folder on demand."""
    return tmp_path_factory.mktemp("doc_fixtures")


def _workspace(tmp_path: Path, made: Path, block: Block) -> Path:
    work = tmp_path / "work"
    work.mkdir()
    if SHARED.is_dir():
        (tmp_path / "shared").symlink_to(SHARED)
    for name in ("examples", "baselines", "scripts", "docs"):
        (work / name).symlink_to(ROOT / name)
    for name in filter(None, (s.strip() for s in block.opts.get("fixtures", "").split(","))):
        assert name in FIXTURES, f"{block.id}: unknown fixture {name!r} (choose from {', '.join(FIXTURES)})"
        src = made / name
        if not src.exists():
            FIXTURES[name](src)
        link = work / name
        link.symlink_to(src, target_is_directory=src.is_dir())
        if name == "run.csv" and (made / "run.csv.json").exists():  # the log's sidecar travels with it
            (work / "run.csv.json").symlink_to(made / "run.csv.json")
    return work


# ------------------------------------------------------------------------------------------------------ running
def _env() -> dict[str, str]:
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), PYTHONWARNINGS="ignore")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH", "")]))
    return env


def _code(block: Block) -> str:
    code = block.code
    for rep in filter(None, block.opts.get("replace", "").split("|")):
        a, _, b = rep.partition(":")
        assert a in code, f"{block.id}: replace={rep} does not match the block"
        code = code.replace(a, b)
    return code


def _argv(words: list[str]) -> list[str]:
    if words[0] == "franka-vs":
        return [sys.executable, "-m", "franka_vs_gym.cli", *words[1:]]
    if words[0] in ("python", "python3"):
        return [sys.executable, *words[1:]]
    return words


def _check_pip(block: Block, words: list[str]) -> None:
    """A documented install: `pip install ...` of this project with extras that exist (CI runs the install itself)."""
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = set(project["optional-dependencies"])
    for w in words[2:]:
        if w.startswith("-e") or w in (".",) or w.startswith("torch=="):
            m = re.search(r"\[(.*)\]", w)
            if m:
                missing = {e.strip() for e in m.group(1).split(",")} - extras
                assert not missing, f"{block.id}: extras {missing} are not in pyproject.toml"
            continue
        if w.startswith("."):
            m = re.search(r"\[(.*)\]", w)
            missing = {e.strip() for e in (m.group(1).split(",") if m else [])} - extras
            assert not missing, f"{block.id}: extras {missing} are not in pyproject.toml"


def _check_synopsis(block: Block, words: list[str], env: dict[str, str]) -> None:
    """`franka-vs cmd [--opt X] ...`: every option named must be accepted by that command."""
    cmd = [w for w in words[:3] if not w.startswith(("-", "["))]
    r = subprocess.run(_argv(cmd + ["--help"]), capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, f"{block.id}: {' '.join(cmd)} --help failed: {r.stderr[-500:]}"
    for opt in re.findall(r"(--[a-z][a-z0-9-]*)", " ".join(words)):
        assert opt in r.stdout, f"{block.id}: {' '.join(cmd)} has no option {opt}"


def _run_bash(block: Block, work: Path, env: dict[str, str], timeout: float) -> None:
    if re.search(r"&\s*(#.*)?$", block.code, re.M):  # a documented server on the default address: one at a time
        import fcntl
        import tempfile

        with open(Path(tempfile.gettempdir()) / "franka_vs_gym_doc_servers.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            _run_lines(block, work, env, timeout)
        return
    _run_lines(block, work, env, timeout)


def _run_lines(block: Block, work: Path, env: dict[str, str], timeout: float) -> None:
    servers: list[subprocess.Popen] = []
    lines, buf = [], ""
    for raw in _code(block).splitlines():  # join continuation lines (a backslash, or a synopsis's "[...]" line)
        if raw.strip().startswith("[") and lines and not buf:
            lines[-1] += " " + raw.strip()
            continue
        buf += raw.rstrip("\\").rstrip() + " " if raw.rstrip().endswith("\\") else raw
        if not raw.rstrip().endswith("\\"):
            lines.append(buf)
            buf = ""
    try:
        for line in lines:
            line = re.split(r"\s#\s?|^#", line, maxsplit=1)[0].strip()
            if not line:
                continue
            for part in (p.strip() for p in line.split("&&")):
                background = part.endswith("&")
                words = shlex.split(part.rstrip("&").strip())
                if words[:2] == ["pip", "install"]:
                    _check_pip(block, words)
                    continue
                if any(w.startswith("[") for w in words):
                    _check_synopsis(block, words, env)
                    continue
                argv = _argv(words)
                if background:
                    p = subprocess.Popen(argv, cwd=work, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                         text=True)
                    servers.append(p)
                    ready = p.stdout.readline()  # a server prints one line when it is ready
                    assert ready, f"{block.id}: {part!r} printed nothing: {p.stderr.read()[-1000:]}"
                    continue
                t0 = time.monotonic()
                r = subprocess.run(argv, cwd=work, env=env, capture_output=True, text=True, timeout=timeout)
                assert r.returncode == 0, (f"{block.id}: {part!r} exited {r.returncode} after "
                                           f"{time.monotonic() - t0:.1f} s:\n{r.stdout[-1500:]}\n{r.stderr[-2500:]}")
    finally:
        for p in servers:
            p.terminate()
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()


def _strip(line: str) -> str:
    return re.split(r"\s#\s|^#", line, maxsplit=1)[0].strip()


def _check_excerpt(block: Block, work: Path, env: dict[str, str]) -> None:
    src = ROOT / block.opts["excerpt"]
    have = {_strip(x) for x in src.read_text().splitlines()}
    missing = [x for x in map(_strip, block.code.splitlines()) if x and x != "..." and x not in have]
    assert not missing, f"{block.id}: lines not in {src.name} (the excerpt drifted): {missing}"
    r = subprocess.run([sys.executable, str(src)], cwd=work, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, f"{block.id}: {src.name} does not run:\n{r.stderr[-2000:]}"


_SHARED_PATH = re.compile(r"\.\./shared/data/[\w.\-/]*[\w\-]")
# a path a script builds: "shared" / "data" / "gaz2019_traj1"
_SHARED_JOIN = re.compile(r"[\"']shared[\"']\s*/\s*[\"']data[\"']\s*/\s*[\"']([\w.\-]+)[\"']")


def _missing_shared_data(block: Block) -> list[str]:
    """The ``../shared/data/...`` paths a block reads (its code, or the file it is an excerpt of) that are absent
    here, e.g. in a plain clone without the shared folder beside it."""
    text = _code(block)
    # data a script finds through its own configuration (e.g. scripts/evaluation_split.json), named by the block
    text += "\n" + "\n".join(f"../shared/data/{p.strip()}" for p in block.opts.get("data", "").split(",") if p.strip())
    files = [block.opts["excerpt"]] if "excerpt" in block.opts else []
    files += re.findall(r"(?:examples|scripts)/[\w/]+\.py", text)  # a script the block runs may read the data
    for f in files:
        if (ROOT / f).is_file():
            src = (ROOT / f).read_text()
            text += "\n" + src + "\n" + "\n".join(f"../shared/data/{m}" for m in _SHARED_JOIN.findall(src))
    return [m for m in _SHARED_PATH.findall(text) if not (SHARED.parent / m[len("../"):]).exists()]


@pytest.mark.parametrize("block", CODE, ids=[b.id for b in CODE])
def test_code_block_runs(block: Block, tmp_path: Path, made: Path) -> None:
    for mod in filter(None, block.opts.get("needs", "").split(",")):
        if importlib.util.find_spec(mod.strip()) is None:
            pytest.skip(f"{block.id} needs {mod} (an extra not installed here)")
    missing = _missing_shared_data(block)
    if missing:
        pytest.skip(f"{block.id} reads {missing[0]}, absent here (the real recordings sit beside the repository "
                    "in ../shared/data, not in a plain clone)")
    if "ci" in block.opts:  # the README's test command: CI runs exactly it (checked here), so it is not run again
        ci = (ROOT / ".ci" / "run").read_text().splitlines()
        assert block.code.strip() in ci, f"{block.id}: the test command differs from what .ci/run runs"
        return
    work = _workspace(tmp_path, made, block)
    env = _env()
    if "excerpt" in block.opts:
        _check_excerpt(block, work, env)
        return
    timeout = float(block.opts.get("timeout", 300))
    if block.lang == "python":
        script = work / "_block.py"
        script.write_text(_code(block))
        r = subprocess.run([sys.executable, str(script)], cwd=work, env=env, capture_output=True, text=True,
                           timeout=timeout)
        assert r.returncode == 0, f"{block.id} failed:\n{r.stdout[-1500:]}\n{r.stderr[-3000:]}"
    else:
        _run_bash(block, work, env, timeout)


@pytest.mark.parametrize("block", JSON, ids=[b.id for b in JSON])
def test_json_block_parses(block: Block) -> None:
    """A documented file format (``json`` block) is valid JSON, so a user can copy it."""
    import json

    json.loads(block.code)


def test_every_block_declares_its_language() -> None:
    """An unlabelled block cannot be tested: every fence names python, bash or text, and no command hides in text."""
    bad = [b.id for b in BLOCKS if b.lang not in LANGS]
    assert not bad, f"blocks without a language among {sorted(LANGS)}: {bad}"
    hidden = [b.id for b in BLOCKS if b.lang == "text"
              and re.match(r"\s*(franka-vs |python |pip |import |from \w+ import)", b.code)]
    assert not hidden, f"commands in text blocks (label them bash or python so they run): {hidden}"


# ------------------------------------------------------------------------------------------------ links, results
_LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")


def _anchors(path: Path) -> set[str]:
    """The anchors GitHub gives a page's headings (lower case, punctuation dropped, spaces to hyphens, repeats
    numbered), written here independently of scripts/results_table.py's slug."""
    seen: dict[str, int] = {}
    out = set()
    text = re.sub(r"^```.*?^```", "", path.read_text(), flags=re.S | re.M)  # no headings inside code blocks
    for m in re.finditer(r"^#{1,6}\s+(.*?)\s*#*\s*$", text, re.M):
        base = "".join(c for c in m.group(1).lower().replace("`", "").replace("*", "")
                       if c.isalnum() or c in "-_ ").replace(" ", "-")
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def test_links_resolve() -> None:
    """Every relative link (and image) in README.md, CHANGELOG.md and docs/ names a file of the repository, and its
    #anchor a heading of that page: moving a section without fixing its links fails here."""
    bad = []
    for path in DOCS:
        text = re.sub(r"^```.*?^```", "", path.read_text(), flags=re.S | re.M)
        for m in _LINK.finditer(text):
            target = m.group(1) or m.group(2)
            if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
                continue
            file, _, anchor = target.partition("#")
            dest = (path.parent / file).resolve() if file else path
            rel = dest.relative_to(ROOT).as_posix() if dest.is_relative_to(ROOT) else str(dest)
            if not dest.exists():
                bad.append(f"{path.relative_to(ROOT)}: {target} (no such file)")
                continue
            if anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
                bad.append(f"{path.relative_to(ROOT)}: {target} (no heading with that anchor in {rel})")
    assert not bad, "broken links:\n" + "\n".join(bad)


def test_doc_paths_named_in_code_exist() -> None:
    """Code, scripts and tests that send the reader to a page (``docs/workbench/method.md``) name a page that exists."""
    bad = []
    for path in [*ROOT.joinpath("franka_vs_gym").rglob("*.py"), *ROOT.joinpath("scripts").glob("*.py"),
                 *ROOT.joinpath("tests").rglob("*.py")]:
        for m in re.finditer(r"\b((?:docs/)[\w./-]+\.md)\b", path.read_text()):
            if not (ROOT / m.group(1)).exists():
                bad.append(f"{path.relative_to(ROOT)}: {m.group(1)}")
    assert not bad, "pages named in code that do not exist:\n" + "\n".join(bad)


def test_results_are_what_the_script_writes() -> None:
    """docs/results.md and the README's results table are scripts/results_table.py's output of docs/results/*.json
    (edit the JSON and run the script; never the generated text)."""
    spec = importlib.util.spec_from_file_location("results_table", ROOT / "scripts" / "results_table.py")
    rt = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rt)
    figures = rt.load()
    assert (ROOT / "docs" / "results.md").read_text() == rt.results_md(figures), \
        "docs/results.md differs from what scripts/results_table.py writes: run python scripts/results_table.py"
    readme = (ROOT / "README.md").read_text()
    assert readme == rt.readme_with_table(readme, figures), \
        "README.md's results table differs from what scripts/results_table.py writes: run it"
    assert len(re.findall(r"docs/results\.md#", readme)) == sum(1 for f in figures if f.get("headline"))


def test_results_script_refuses_a_bad_figure_file(tmp_path: Path) -> None:
    """A figure file with an unknown key or a short table row is refused in one line naming the file; nothing is
    assembled from it."""
    import json

    spec = importlib.util.spec_from_file_location("results_table", ROOT / "scripts" / "results_table.py")
    rt = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rt)
    good = {"title": "A figure", "area": "Speed", "order": 1, "command": "python scripts/bench.py", "date": "today",
            "table": {"columns": ["a", "b"], "rows": [["1", "2"]]}, "headline": {"what": "a", "figure": "1"}}
    (tmp_path / "a.json").write_text(json.dumps(good))
    assert "| a | 1 |" in rt.readme_table(rt.load(tmp_path))
    for bad, says in [({**good, "colour": "red"}, "unknown key(s) colour"),
                      ({**good, "table": {"columns": ["a", "b"], "rows": [["1"]]}}, "row 0 has 1 cells"),
                      ({**good, "area": "Elsewhere"}, "area 'Elsewhere'"),
                      ({k: v for k, v in good.items() if k != "date"}, "missing key(s) date")]:
        (tmp_path / "a.json").write_text(json.dumps(bad))
        with pytest.raises(rt.FigureError, match=re.escape(says)):
            rt.load(tmp_path)
