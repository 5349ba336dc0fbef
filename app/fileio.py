"""Atomic file output: write to a temporary file beside the target, then rename, so a
crash or an error never leaves a half-written file under the target's name. The file gets
the mode a plain ``open(path, "w")`` would give it (0o666 masked by the umask), not the
0600 of ``tempfile.mkstemp``.

Also the output-path checks both command-line tools apply to every path they write:
an output shall not be one of the inputs (or another output), and shall be writable."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import IO, Iterator

from ..common.errors import LghccError


def default_file_mode() -> int:
    """0o666 masked by the process umask: the mode ``open()`` gives a new file."""
    try:  # Linux >= 4.7 shows the umask without changing it (safe with other threads)
        with open("/proc/self/status", encoding="ascii") as f:
            mask = next(int(line.split()[1], 8) for line in f if line.startswith("Umask:"))
    except (OSError, StopIteration, ValueError, IndexError):
        mask = os.umask(0)  # elsewhere it can only be read by setting it; set it straight back
        os.umask(mask)
    return 0o666 & ~mask


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, mode: str = "wb") -> Iterator[IO]:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, mode) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
            os.fchmod(f.fileno(), default_file_mode())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_output(path) as f:
        f.write(data)


def same_path(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """True when a and b name the same file: the same inode when both exist (hard and
    symbolic links included), else the same resolved path."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return Path(a).resolve() == Path(b).resolve()


def check_output_paths(outputs: dict[str, str | os.PathLike | None],
                       inputs: dict[str, str | os.PathLike | None]) -> None:
    """Raise LghccError when an output path (option name -> path; None = not given) names
    one of the inputs or another output, so that no run overwrites its own input."""
    given = [(k, v) for k, v in outputs.items() if v is not None]
    for i, (opt, out) in enumerate(given):
        for what, src in inputs.items():
            if src is not None and same_path(out, src):
                raise LghccError(f"{opt} {out} would overwrite the {what} {src}")
        for opt2, out2 in given[:i]:
            if same_path(out, out2):
                raise LghccError(f"{opt} {out} and {opt2} {out2} are the same file")


def check_writable_file(path: str | os.PathLike, what: str = "") -> None:
    """Fail early (before minutes of work) when a file cannot be created at path: raise
    LghccError "cannot write PATH (reason)". Creates and removes a temporary file beside it
    when its folder exists; never creates folders."""
    p = Path(path)
    label = f"{what} {p}" if what else str(p)
    if p.is_dir():
        raise LghccError(f"cannot write {label} (it is a folder)")
    folder = p.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise LghccError(f"cannot write {label} ({folder} is not a folder)")
    if folder != p.parent:  # the folder will be created: check its existing ancestor
        if not os.access(folder, os.W_OK | os.X_OK):
            raise LghccError(f"cannot write {label} (no permission to create folders in {folder})")
        return
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".probe", dir=folder)
    except OSError as e:
        raise LghccError(f"cannot write {label} ({e.strerror or e})") from None
    os.close(fd)
    os.unlink(tmp)


def write_error(path: str | os.PathLike, e: OSError) -> LghccError:
    """The LghccError to raise for an OSError while writing path."""
    return LghccError(f"cannot write {path} ({e.strerror or e})")


def check_overwrite(path: str | os.PathLike, overwrite: bool, what: str = "") -> None:
    """The overwrite rule for an output file (common/cliargs.OVERWRITE_RULE): LghccError when
    ``path`` exists and ``overwrite`` is false, or is a folder; then whether it can be written."""
    p = Path(path)
    label = f"{what} {p}" if what else str(p)
    if p.is_dir():
        raise LghccError(f"cannot write {label} (it is a folder)")
    if p.exists() and not overwrite:
        raise LghccError(f"{label} exists; use -y (--overwrite) to replace it")
    check_writable_file(p, what)


def check_output_folder(path: str | os.PathLike, overwrite: bool, what: str = "",
                        replaced: str = "the files written there are replaced; others are left as they are") -> None:
    """The overwrite rule for an output folder: an existing non-empty folder needs
    ``overwrite``; an existing file is an error; a new folder must be creatable. Raises
    LghccError before any work is done."""
    p = Path(path)
    label = f"{what} {p}" if what else str(p)
    if p.exists() and not p.is_dir():
        raise LghccError(f"cannot write {label} (it exists and is not a folder)")
    if p.is_dir():
        if any(p.iterdir()) and not overwrite:
            raise LghccError(f"{label} is not empty; use -y (--overwrite) to write into it ({replaced})")
        if not os.access(p, os.W_OK | os.X_OK):
            raise LghccError(f"cannot write {label} (permission denied)")
        return
    parent = p.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise LghccError(f"cannot write {label} (cannot create a folder in {parent})")
