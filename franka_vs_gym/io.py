"""Safe files: outputs that never replace what they should not, inputs that never hang or exhaust memory.

Writing
-------
- :func:`atomic_write` writes one file through a unique temporary file in the target folder (``tempfile``), fsyncs
  it and renames it into place: readers see the old file or the new one, never half of one, and two concurrent
  writers never share a temporary. An existing file is replaced only with ``force=True`` (without it the final link
  is made with ``os.link``, which fails if another writer got there first), and a file the command reads is never
  written, whatever ``force`` says.
- :class:`OutputSet` makes several files and folders (e.g. a calibrated model and its report folder) appear together
  or not at all: each is staged next to its target and renamed into place at :meth:`OutputSet.commit`; an error
  before that removes the staging and leaves the targets untouched.
- :func:`atomic_open` is the context-manager form of :func:`atomic_write` for writers that want a file object.

Reading
-------
- :func:`check_input_file` / :func:`open_input` accept regular files only (a FIFO, a device such as ``/dev/zero``, a
  socket or a folder where a file is expected is refused with a one-line :class:`~franka_vs_gym.errors.UserError`),
  check the size before anything is allocated, and open without blocking (``O_NONBLOCK``), so nothing hangs.
- :func:`load_npz` checks every array's header (dtype, shape, and that the declared size fits the stored bytes)
  before reading it, and memory-maps uncompressed members.

Inputs of a command
-------------------
Inside :func:`command_scope` (the ``franka-vs`` command enters one per run), every file opened through this module
is remembered, and no output may be written over it: ``franka-vs fit LOG -o LOG --force`` is refused.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import stat
import tempfile
import zipfile
import zlib
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from franka_vs_gym.errors import UserError

PathLike = str | os.PathLike
# Default size limits: a log of a few hours at 1 kHz is well below these.
MAX_INPUT_BYTES = 4 * 1024**3
MAX_TEXT_BYTES = 16 * 1024**2  # JSON sidecars, model files
MAX_ARRAY_ELEMENTS = 2 * 1024**3 // 8

# ------------------------------------------------------------------------------------------- inputs of a command
_scope: list[set[tuple[int, int] | str]] = []


@contextlib.contextmanager
def command_scope() -> Iterator[None]:
    """Remember every input opened through this module until the scope ends; outputs refuse to replace them."""
    _scope.append(set())
    try:
        yield
    finally:
        _scope.pop()
        _active_runs.clear()


def _identity(p: Path) -> tuple[int, int] | str:
    try:
        st = os.stat(p)
        return (st.st_dev, st.st_ino)
    except OSError:
        return str(Path(os.path.abspath(p)))


def register_input(path: PathLike) -> None:
    """Declare ``path`` an input of the running command (no-op outside :func:`command_scope`)."""
    if _scope:
        _scope[-1].add(_identity(Path(path)))


def _is_input(p: Path, inputs: Iterable[PathLike]) -> bool:
    ident = _identity(p)
    if isinstance(ident, str) and not os.path.lexists(p):
        return False
    known = set(_scope[-1]) if _scope else set()
    known.update(_identity(Path(i)) for i in inputs)
    return ident in known


# ------------------------------------------------------------------------------------------- reading
_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def _fmt_bytes(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 1024 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} B"


def check_input_file(path: PathLike, what: str = "input file", max_bytes: int | None = MAX_INPUT_BYTES) -> Path:
    """``path`` as a Path if it is an existing regular file of at most ``max_bytes``.

    Raises FileNotFoundError if it does not exist, :class:`UserError` if it is a folder, FIFO, device or socket (or
    a link to one, such as ``/dev/zero``) or too large. Registers it as an input of the running command.
    """
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} not found: {p}") from None
    except NotADirectoryError:
        raise FileNotFoundError(f"{what} not found: {p} (a parent is not a folder)") from None
    except PermissionError:
        raise UserError(f"{what} {p}: permission denied") from None
    _check_stat(p, st, what, max_bytes)
    register_input(p)
    return p


def _check_stat(p: Path, st: os.stat_result, what: str, max_bytes: int | None) -> None:
    if not stat.S_ISREG(st.st_mode):
        raise UserError(f"{what} {p} is {_kind(st.st_mode)}, expected a regular file")
    if max_bytes is not None and st.st_size > max_bytes:
        raise UserError(f"{what} {p} is {_fmt_bytes(st.st_size)}, more than the {_fmt_bytes(max_bytes)} allowed")


def check_input_folder(path: PathLike, what: str = "input folder") -> Path:
    """``path`` as a Path if it is an existing folder (FileNotFoundError / UserError otherwise)."""
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} not found: {p}") from None
    if not stat.S_ISDIR(st.st_mode):
        raise UserError(f"{what} {p} is {_kind(st.st_mode) if not stat.S_ISREG(st.st_mode) else 'a file'}, "
                        "expected a folder")
    return p


def open_input(path: PathLike, mode: str = "rb", what: str = "input file", max_bytes: int | None = MAX_INPUT_BYTES,
               **kwargs: Any) -> IO[Any]:
    """Open a regular file for reading (``mode`` "rb" or "r"; ``kwargs`` go to ``open``), never blocking.

    The file is opened with ``O_NONBLOCK`` and checked with ``fstat`` on the open descriptor (so a FIFO swapped in
    after a check cannot hang the reader); then the same checks as :func:`check_input_file` apply.
    """
    if mode not in ("r", "rb"):
        raise ValueError(f"open_input reads only (mode 'r' or 'rb'), got {mode!r}")
    p = Path(path)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(p, flags)
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} not found: {p}") from None
    except IsADirectoryError:
        raise UserError(f"{what} {p} is a folder, expected a regular file") from None
    except PermissionError:
        raise UserError(f"{what} {p}: permission denied") from None
    try:
        st = os.fstat(fd)
        _check_stat(p, st, what, max_bytes)
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        fh = os.fdopen(fd, mode, **kwargs)
    except BaseException:
        os.close(fd)
        raise
    register_input(p)
    return fh


def read_text(path: PathLike, what: str = "file", max_bytes: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of a small regular file (sidecars, model files); UserError if it is not UTF-8 text."""
    with open_input(path, "rb", what=what, max_bytes=max_bytes) as fh:
        raw = fh.read()
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise UserError(f"{what} {path} is not UTF-8 text (byte {e.start})") from None


def loads_json(text: str, where: str) -> Any:
    """``json.loads``; JSON nested deeper than Python's parser can follow (a RecursionError) is a UserError naming
    ``where``. Syntax errors stay ``json.JSONDecodeError`` for the caller to word."""
    import json

    try:
        return json.loads(text)
    except RecursionError:
        raise UserError(f"{where}: JSON nested too deeply to read") from None


def _npy_header(fh: IO[bytes], name: str, where: str) -> tuple[tuple[int, ...], bool, np.dtype]:
    fmt = np.lib.format
    try:
        version = fmt.read_magic(fh)
        if version == (1, 0):
            shape, fortran, dtype = fmt.read_array_header_1_0(fh)
        elif version in ((2, 0), (3, 0)):
            shape, fortran, dtype = fmt.read_array_header_2_0(fh)
        else:
            raise ValueError(f"unsupported .npy version {version}")
    except Exception as e:  # numpy parses the header with ast/tokenize: any failure means a malformed header
        raise UserError(f"{where}: array {name!r} has a malformed header ({' '.join(str(e).split())})") from None
    if dtype.hasobject:
        raise UserError(f"{where}: array {name!r} holds Python objects; only numeric arrays are read")
    return shape, fortran, dtype


def load_npz(path: PathLike, what: str = "NPZ file", max_bytes: int | None = MAX_INPUT_BYTES,
             max_elements: int = MAX_ARRAY_ELEMENTS, names: Iterable[str] | None = None,
             mmap: bool = True) -> dict[str, np.ndarray]:
    """Read the arrays of an ``.npz`` file after checking each header.

    Every member's declared dtype and shape are read first; a member whose declared size exceeds ``max_elements``
    or the bytes it actually holds (a truncated or forged file), or that holds Python objects, is refused with a
    :class:`UserError` before anything is allocated. Uncompressed members are memory-mapped read-only when ``mmap``
    (np.savez); compressed ones (np.savez_compressed) are decompressed. ``names`` restricts which arrays are read.
    Returns ``{name: array}`` (names without ``.npy``).
    """
    p = check_input_file(path, what, max_bytes)
    try:
        zf = zipfile.ZipFile(p)
    except zipfile.BadZipFile:
        raise UserError(f"{what} {p} is not a valid .npz archive (empty, truncated or another format)") from None
    except OSError as e:
        raise UserError(f"{what} {p}: {e.strerror or e}") from None
    want = None if names is None else set(names)
    out: dict[str, np.ndarray] = {}
    with zf:
        for info in zf.infolist():
            if not info.filename.endswith(".npy"):
                continue
            name = info.filename[:-4]
            if want is not None and name not in want:
                continue
            try:
                with zf.open(info) as fh:
                    shape, fortran, dtype = _npy_header(fh, name, f"{what} {p}")
                    header_len = fh.tell()
                    n = int(np.prod(shape, dtype=np.int64)) if shape else 1
                    if n > max_elements:
                        raise UserError(f"{what} {p}: array {name!r} declares shape {shape} ({n} values), more "
                                        f"than the {max_elements} allowed")
                    need = n * dtype.itemsize
                    have = info.file_size - header_len
                    if need > have:
                        raise UserError(f"{what} {p}: array {name!r} declares shape {shape} ({need} bytes) but holds "
                                        f"{max(have, 0)} bytes (truncated or corrupt file)")
                    if mmap and info.compress_type == zipfile.ZIP_STORED and n > 0:
                        arr = _memmap_member(p, zf, info, header_len, shape, fortran, dtype)
                    else:
                        arr = np.frombuffer(_read_exact(fh, need, name, p, what), dtype=dtype, count=n)
                        arr = arr.reshape(shape, order="F" if fortran else "C")
            except (zipfile.BadZipFile, EOFError, zlib.error) as e:
                raise UserError(f"{what} {p}: array {name!r} cannot be read ({' '.join(str(e).split())}); "
                                "truncated or corrupt file") from None
            out[name] = arr
    return out


def _read_exact(fh: IO[bytes], n: int, name: str, p: Path, what: str) -> bytes:
    buf = fh.read(n)
    if len(buf) != n:
        raise UserError(f"{what} {p}: array {name!r} is truncated ({len(buf)} of {n} bytes)")
    return buf


def _memmap_member(p: Path, zf: zipfile.ZipFile, info: zipfile.ZipInfo, header_len: int, shape: tuple[int, ...],
                   fortran: bool, dtype: np.dtype) -> np.ndarray:
    # offset of the member's data: local file header (30 bytes + name + extra) after header_offset
    fp = zf.fp
    assert fp is not None
    fp.seek(info.header_offset)
    local = fp.read(30)
    if len(local) != 30 or local[:4] != b"PK\x03\x04":
        raise zipfile.BadZipFile("bad local file header")
    n_name = int.from_bytes(local[26:28], "little")
    n_extra = int.from_bytes(local[28:30], "little")
    offset = info.header_offset + 30 + n_name + n_extra + header_len
    return np.memmap(p, dtype=dtype, mode="r", offset=offset, shape=shape, order="F" if fortran else "C")


# ------------------------------------------------------------------------------------------- writing
def check_output(path: PathLike, force: bool = False, inputs: Iterable[PathLike] = (), what: str = "output",
                 folder: bool = False) -> Path:
    """Refuse an output path early, with a one-line error: a file the command reads (always), an existing file or
    folder without ``force``, a file where a folder is expected (or the reverse), a parent that is not a writable
    folder. Returns the path."""
    p = Path(path)
    if str(path) == "" or p.name in ("", ".", ".."):
        raise UserError(f"{what} path {str(path)!r} does not name a file")
    if _is_input(p, inputs):
        raise UserError(f"{what} {p} is one of this command's inputs; refusing to write over it (choose another "
                        "path)")
    if os.path.lexists(p):
        is_dir = p.is_dir() and not p.is_symlink()
        if folder and not is_dir:
            raise UserError(f"{what} {p} exists and is not a folder")
        if not folder and is_dir:
            raise UserError(f"{what} {p} is a folder, expected a file path")
        if not force:
            raise FileExistsError(f"{what} {p} exists; pass --force to replace it")
        if not folder and not stat.S_ISREG(os.stat(p).st_mode):
            raise UserError(f"{what} {p} is {_kind(os.stat(p).st_mode)}; refusing to replace it")
    parent = p.parent if str(p.parent) else Path(".")
    if os.path.lexists(parent):
        if not parent.is_dir():
            raise UserError(f"{what} {p}: {parent} is not a folder")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise UserError(f"{what} {p}: folder {parent} is not writable")
    return p


def _ensure_parent(p: Path, what: str) -> None:
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise UserError(f"{what} {p}: {p.parent} is not a folder") from None
    except PermissionError:
        raise UserError(f"{what} {p}: cannot create folder {p.parent} (permission denied)") from None
    except NotADirectoryError:
        raise UserError(f"{what} {p}: a parent of {p.parent} is not a folder") from None


def _fsync_dir(d: Path) -> None:
    try:
        fd = os.open(d, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _place(tmp: Path, target: Path, force: bool, what: str) -> None:
    """Rename ``tmp`` to ``target``; without ``force`` this fails if ``target`` appeared meanwhile."""
    if force:
        os.replace(tmp, target)
        return
    try:
        os.link(tmp, target)
    except FileExistsError:
        raise FileExistsError(f"{what} {target} exists; pass --force to replace it") from None
    except OSError:
        # file systems without hard links: check, then rename (a small window remains)
        if os.path.lexists(target):
            raise FileExistsError(f"{what} {target} exists; pass --force to replace it") from None
        os.replace(tmp, target)
        return
    os.unlink(tmp)


def _stage_file(target: Path) -> Path:
    fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".partial", dir=target.parent)
    os.close(fd)
    return Path(name)


def atomic_write(path: PathLike, data: str | bytes | Callable[[IO[Any]], Any], *, force: bool = False,
                 inputs: Iterable[PathLike] = (), what: str = "output", encoding: str = "utf-8") -> Path:
    """Write ``data`` to ``path`` atomically: a str (text, ``encoding``), bytes, or a function that writes to the
    binary file object it is given (e.g. ``lambda fh: np.savez(fh, **arrays)``).

    A unique temporary file in the target folder receives the data, is fsynced and renamed into place. Refuses
    (one-line error) to write over one of ``inputs`` or an input of the running command, and to replace an existing
    file unless ``force``. On any error the temporary file is removed and the target is untouched. Returns the path.
    """
    with atomic_open(path, "w" if isinstance(data, str) else "wb", force=force, inputs=inputs, what=what,
                     encoding=encoding) as fh:
        if callable(data):
            data(fh)
        else:
            fh.write(data)
    return Path(path)


@contextlib.contextmanager
def atomic_open(path: PathLike, mode: str = "wb", *, force: bool = False, inputs: Iterable[PathLike] = (),
                what: str = "output", encoding: str = "utf-8") -> Iterator[IO[Any]]:
    """Context manager yielding a file object (``mode`` "w" or "wb") whose content replaces ``path`` atomically
    when the block ends without an exception (see :func:`atomic_write`)."""
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open writes whole files (mode 'w' or 'wb'), got {mode!r}")
    p = check_output(path, force, inputs, what)
    _ensure_parent(p, what)
    try:
        tmp = _stage_file(p)
    except PermissionError:
        raise UserError(f"{what} {p}: folder {p.parent} is not writable") from None
    try:
        with open(tmp, mode, **({"encoding": encoding, "newline": ""} if mode == "w" else {})) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        _place(tmp, p, force, what)
        _fsync_dir(p.parent)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)


def _umask() -> int:
    m = os.umask(0)
    os.umask(m)
    return m


class OutputSet:
    """Several output files and folders that appear together or not at all.

    Usage::

        with OutputSet(force=args.force, inputs=[log]) as out:
            model_tmp = out.file("calibrated.json")      # a staging path: write the file there
            report_tmp = out.folder("report")           # a staging folder: fill it
            ...
        # here both calibrated.json and report/ exist, complete; after an exception neither was touched

    Targets are checked when registered (so a refusal comes before any long computation) and again at commit.
    Each is staged in its own target folder (a hidden ``.<name>.*.partial`` sibling) and renamed into place at
    :meth:`commit`; if a rename fails, the targets already placed are restored (old content back, new removed).
    With ``force``, existing targets are replaced (a folder as a whole). Inputs of the command are never targets.
    """

    def __init__(self, *, force: bool = False, inputs: Iterable[PathLike] = ()) -> None:
        self.force = bool(force)
        self.inputs = [Path(i) for i in inputs]
        self._items: list[tuple[Path, Path, bool, str]] = []  # (target, staging, is_folder, what)
        self.committed = False

    def _claim(self, path: PathLike, folder: bool, what: str) -> Path:
        if self.committed:
            raise RuntimeError("OutputSet already committed")
        p = check_output(path, self.force, self.inputs, what, folder=folder)
        if any(os.path.abspath(t) == os.path.abspath(p) for t, *_ in self._items):
            raise UserError(f"{what} {p} is named twice among this command's outputs")
        _ensure_parent(p, what)
        try:
            if folder:
                stage = Path(tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".partial", dir=p.parent))
            else:
                stage = _stage_file(p)
        except PermissionError:
            raise UserError(f"{what} {p}: folder {p.parent} is not writable") from None
        self._items.append((p, stage, folder, what))
        return stage

    def file(self, path: PathLike, what: str = "output") -> Path:
        """Register output file ``path``; returns the staging path to write it to."""
        return self._claim(path, False, what)

    def folder(self, path: PathLike, what: str = "output folder") -> Path:
        """Register output folder ``path``; returns the (created, empty) staging folder to fill."""
        return self._claim(path, True, what)

    def commit(self) -> list[Path]:
        """Move every staged output into place; all or nothing. Returns the target paths."""
        for target, stage, folder, what in self._items:
            check_output(target, self.force, self.inputs, what, folder=folder)
            if not folder:
                with open(stage, "rb+") as fh:
                    os.fsync(fh.fileno())
                os.chmod(stage, 0o666 & ~_umask())
        done: list[tuple[Path, Path | None]] = []  # (target, backup of the old content)
        pending: tuple[Path, Path] | None = None
        try:
            for target, stage, folder, what in self._items:
                backup = None
                if os.path.lexists(target):
                    backup = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
                    backup = backup / target.name
                    if not folder and not target.is_dir():
                        # a file is replaced in one atomic rename: readers of the path never find it missing; the
                        # old content stays reachable through a hard link (a copy where links are not supported)
                        try:
                            os.link(target, backup, follow_symlinks=False)
                        except OSError:
                            shutil.copy2(target, backup, follow_symlinks=False)
                        pending = (target, backup)
                        os.replace(stage, target)
                    else:
                        os.rename(target, backup)
                        pending = (target, backup)
                        os.rename(stage, target)
                elif not folder:
                    _place(stage, target, False, what)
                else:
                    os.rename(stage, target)
                pending = None
                done.append((target, backup))
        except BaseException:
            if pending is not None:  # the old content was moved aside but the new one not placed
                with contextlib.suppress(OSError):
                    os.rename(pending[1], pending[0])
                    os.rmdir(pending[1].parent)
            for target, backup in reversed(done):
                if backup is not None and not backup.is_dir() and not target.is_dir():
                    with contextlib.suppress(OSError):  # the old file back in one rename
                        os.replace(backup, target)
                        os.rmdir(backup.parent)
                    continue
                with contextlib.suppress(OSError):
                    if target.is_dir() and not target.is_symlink():
                        shutil.rmtree(target)
                    else:
                        os.unlink(target)
                if backup is not None:
                    with contextlib.suppress(OSError):
                        os.rename(backup, target)
                        os.rmdir(backup.parent)
            self.discard()
            raise
        for _target, backup in done:
            if backup is not None:
                shutil.rmtree(backup.parent, ignore_errors=True)
        for target, *_ in self._items:
            _fsync_dir(target.parent)
        self.committed = True
        return [t for t, *_ in self._items]

    def discard(self) -> None:
        """Remove every staging file and folder (the targets are untouched)."""
        for _target, stage, folder, _what in self._items:
            if folder:
                shutil.rmtree(stage, ignore_errors=True)
            else:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(stage)
        self._items.clear()

    def __enter__(self) -> OutputSet:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None and not self.committed:
            self.commit()
        elif exc_type is not None:
            self.discard()


# ------------------------------------------------------------------------------------------- run folders
_active_runs: list[Path] = []


def track_run(folder: PathLike) -> None:
    """Declare ``folder`` a run folder being filled (an interrupted command renames it ``...-incomplete``)."""
    _active_runs.append(Path(folder))


def finish_run(folder: PathLike) -> None:
    """The run in ``folder`` completed."""
    p = Path(folder)
    if p in _active_runs:
        _active_runs.remove(p)


def abandon_runs() -> list[str]:
    """After an interruption: rename each unfinished run folder to ``<name>-incomplete`` (removed when empty).
    Returns one phrase per folder for the user."""
    out = []
    while _active_runs:
        p = _active_runs.pop()
        if not p.is_dir():
            continue
        if not any(p.iterdir()):
            with contextlib.suppress(OSError):
                p.rmdir()
                out.append(f"empty run folder {p} removed")
            continue
        target = p.with_name(p.name + "-incomplete")
        k = 2
        while os.path.lexists(target):
            target = p.with_name(f"{p.name}-incomplete-{k}")
            k += 1
        try:
            os.rename(p, target)
            out.append(f"partial run kept in {target}")
        except OSError:
            out.append(f"partial run left in {p}")
    return out


__all__ = ["MAX_INPUT_BYTES", "OutputSet", "abandon_runs", "atomic_open", "atomic_write", "check_input_file",
           "check_input_folder", "check_output", "command_scope", "finish_run", "load_npz", "open_input",
           "read_text", "register_input", "track_run"]
