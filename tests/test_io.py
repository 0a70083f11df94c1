"""Safe files (franka_vs_gym.io): atomic outputs, all-or-nothing output sets, inputs that never hang."""

from __future__ import annotations

import io as pyio
import os
import threading
import zipfile

import numpy as np
import pytest

from franka_vs_gym import io
from franka_vs_gym.errors import UserError


def test_atomic_write_creates_and_refuses_to_replace(tmp_path):
    p = tmp_path / "a" / "out.json"
    io.atomic_write(p, "one")
    assert p.read_text() == "one"
    with pytest.raises(FileExistsError, match="--force"):
        io.atomic_write(p, "two")
    assert p.read_text() == "one"
    io.atomic_write(p, "two", force=True)
    assert p.read_text() == "two"
    assert sorted(x.name for x in p.parent.iterdir()) == ["out.json"]  # no temporaries left


def test_atomic_write_error_leaves_target_untouched(tmp_path):
    p = tmp_path / "out.bin"
    p.write_bytes(b"old")

    def boom(fh):
        fh.write(b"half")
        raise RuntimeError("writer failed")

    with pytest.raises(RuntimeError):
        io.atomic_write(p, boom, force=True)
    assert p.read_bytes() == b"old"
    assert [x.name for x in tmp_path.iterdir()] == ["out.bin"]


def test_atomic_write_refuses_inputs_whatever_force(tmp_path):
    p = tmp_path / "log.csv"
    p.write_text("x")
    with pytest.raises(UserError, match="inputs"):
        io.atomic_write(p, "y", force=True, inputs=[p])
    link = tmp_path / "alias.csv"
    os.link(p, link)  # the same file under another name
    with pytest.raises(UserError, match="inputs"):
        io.atomic_write(link, "y", force=True, inputs=[p])
    with io.command_scope():
        io.check_input_file(p)
        with pytest.raises(UserError, match="inputs"):
            io.atomic_write(tmp_path / "log.csv", "y", force=True)
    io.atomic_write(p, "z", force=True)  # outside the scope the file is no longer an input
    assert p.read_text() == "z"


def test_concurrent_writers_use_distinct_temporaries(tmp_path):
    p = tmp_path / "out.txt"
    errors = []

    def write(k):
        try:
            for _ in range(20):
                io.atomic_write(p, str(k) * 10000, force=True)
        except Exception as e:  # pragma: no cover - the test fails below
            errors.append(e)

    ts = [threading.Thread(target=write, args=(k,)) for k in range(4)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert not errors
    text = p.read_text()
    assert len(text) == 10000 and len(set(text)) == 1  # one writer's complete content
    assert [x.name for x in tmp_path.iterdir()] == ["out.txt"]


def test_output_paths_refused_early(tmp_path):
    (tmp_path / "d").mkdir()
    with pytest.raises(UserError, match="is a folder"):
        io.atomic_write(tmp_path / "d", "x", force=True)
    (tmp_path / "f").write_text("x")
    with pytest.raises(UserError, match="not a folder"):
        io.atomic_write(tmp_path / "f" / "out.json", "x")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        if os.access(ro, os.W_OK):
            pytest.skip("running as root: permissions are not enforced")
        with pytest.raises(UserError, match="not writable"):
            io.atomic_write(ro / "out.json", "x")
    finally:
        ro.chmod(0o700)


def test_output_set_all_or_nothing(tmp_path):
    model, report = tmp_path / "model.json", tmp_path / "report"
    with pytest.raises(RuntimeError):
        with io.OutputSet() as out:
            out.file(model).write_text("{}")
            (out.folder(report) / "fig.png").write_bytes(b"png")
            raise RuntimeError("report step failed")
    assert sorted(os.listdir(tmp_path)) == []
    with io.OutputSet() as out:
        out.file(model).write_text("{}")
        (out.folder(report) / "fig.png").write_bytes(b"png")
        assert not model.exists() and not report.exists()
    assert model.read_text() == "{}" and (report / "fig.png").read_bytes() == b"png"
    assert sorted(os.listdir(tmp_path)) == ["model.json", "report"]
    # existing targets: refused without force, checked before any work
    with pytest.raises(FileExistsError):
        io.OutputSet().folder(report)
    with io.OutputSet(force=True) as out:
        out.file(model).write_text("{1}")
        (out.folder(report) / "new.md").write_text("new")
    assert model.read_text() == "{1}" and sorted(os.listdir(report)) == ["new.md"]
    assert sorted(os.listdir(tmp_path)) == ["model.json", "report"]


def test_output_set_rolls_back_when_a_rename_fails(tmp_path, monkeypatch):
    a, b = tmp_path / "a.json", tmp_path / "b"
    a.write_text("old a")
    out = io.OutputSet(force=True)
    out.file(a).write_text("new a")
    out.folder(b)
    real_rename = os.rename

    def failing(src, dst):
        if str(dst) == str(b):
            raise OSError(28, "No space left on device", str(dst))
        return real_rename(src, dst)

    monkeypatch.setattr(os, "rename", failing)
    with pytest.raises(OSError):
        out.commit()
    monkeypatch.undo()
    assert a.read_text() == "old a" and not b.exists()
    assert sorted(os.listdir(tmp_path)) == ["a.json"]


@pytest.mark.parametrize("kind", ["fifo", "dev_zero_link", "folder", "missing"])
def test_inputs_that_are_not_regular_files(tmp_path, kind):
    p = tmp_path / "log.csv"
    if kind == "fifo":
        os.mkfifo(p)
    elif kind == "dev_zero_link":
        p.symlink_to("/dev/zero")
    elif kind == "folder":
        p.mkdir()
    exc = FileNotFoundError if kind == "missing" else UserError
    word = {"fifo": "FIFO", "dev_zero_link": "character device", "folder": "folder", "missing": "not found"}[kind]
    with pytest.raises(exc, match=word):
        io.check_input_file(p)
    with pytest.raises(exc, match=word):
        io.open_input(p).close()


def test_input_size_limit(tmp_path):
    p = tmp_path / "big.json"
    p.write_bytes(b" " * 2000)
    with pytest.raises(UserError, match="more than"):
        io.read_text(p, max_bytes=1000)
    assert io.read_text(p, max_bytes=4000) == " " * 2000


def _npz_bytes(**arrays):
    buf = pyio.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def test_load_npz_memory_maps_and_reads_compressed(tmp_path):
    a = np.arange(21.0).reshape(3, 7)
    p = tmp_path / "x.npz"
    np.savez(p, q=a, t=np.arange(3.0))
    z = io.load_npz(p)
    assert isinstance(z["q"], np.memmap) and np.array_equal(z["q"], a)
    pc = tmp_path / "c.npz"
    np.savez_compressed(pc, q=a)
    assert np.array_equal(io.load_npz(pc)["q"], a)


def _forge_shape(data: bytes, new_shape: str) -> bytes:
    """An npz whose array header declares another shape (same header length)."""
    zin = zipfile.ZipFile(pyio.BytesIO(data))
    out = pyio.BytesIO()
    with zipfile.ZipFile(out, "w") as zout:
        for info in zin.infolist():
            raw = zin.read(info)
            start = raw.index(b"'shape': (") + len(b"'shape': (")
            end = raw.index(b")", start)
            old = raw[start:end]
            new = new_shape.encode().ljust(len(old))[: max(len(old), len(new_shape))]
            raw = raw[:start] + new + raw[end:]
            zout.writestr(info.filename, raw)
    return out.getvalue()


@pytest.mark.parametrize("case,word", [
    ("empty", "not a valid .npz"),
    ("truncated", "not a valid .npz"),
    ("huge_shape", "declares shape"),
    ("object", "Python objects"),
    ("text", "not a valid .npz"),
])
def test_load_npz_refuses_bad_archives(tmp_path, case, word):
    p = tmp_path / "bad.npz"
    good = _npz_bytes(q=np.zeros((100, 7)))
    if case == "empty":
        p.write_bytes(b"")
    elif case == "truncated":
        p.write_bytes(good[: len(good) // 2])
    elif case == "huge_shape":
        p.write_bytes(_forge_shape(good, "99999999999, 7"))
    elif case == "object":
        buf = pyio.BytesIO()
        np.savez(buf, q=np.array([{"a": 1}], dtype=object))
        p.write_bytes(buf.getvalue())
    else:
        p.write_text("time,q[0]\n0,1\n")
    before = p.read_bytes()
    with pytest.raises(UserError, match=word):
        io.load_npz(p)
    assert p.read_bytes() == before


def test_abandon_runs(tmp_path):
    full, empty = tmp_path / "run-1", tmp_path / "run-2"
    full.mkdir()
    (full / "metrics.json").write_text("{}")
    empty.mkdir()
    io.track_run(full)
    io.track_run(empty)
    notes = io.abandon_runs()
    assert sorted(os.listdir(tmp_path)) == ["run-1-incomplete"]
    assert any("run-1-incomplete" in n for n in notes)
