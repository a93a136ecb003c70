"""User-facing errors and atomic outputs.

Library code raises :class:`LdlError` (or a subclass) with a one-line message for anything a
user can fix: missing or corrupt files, bad shapes, NaNs, wrong format versions. The CLIs turn
it into ``error: <message>`` on stderr and exit code 1 (see :func:`ldlmap.cli_common.main`).

Outputs are written through :func:`atomic_file` / :func:`atomic_dir`: to a temporary sibling
that is renamed into place only when the ``with`` block succeeds, so a failed or interrupted
command never leaves a half-written file behind.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterable, Iterator


class LdlError(Exception):
    """An error whose message is shown to the user as one line (no traceback)."""


class InputError(LdlError):
    """Missing, unreadable, corrupt or invalid input."""


class FormatVersionError(LdlError):
    """A file written by another (newer or older) format version."""


def require_file(path: str | os.PathLike, what: str = "file") -> Path:
    """Return ``path`` as a Path, raising :class:`InputError` when it is not an existing file."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{what} not found: {p}")
    if not p.is_file():
        raise InputError(f"{what} is not a file: {p}")
    return p


def _same_path(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name the same file or folder (symlinks resolved, hard links too)."""
    if a.resolve() == b.resolve():
        return True
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _holds(folder: Path, path: Path) -> bool:
    """Whether ``path`` lies inside ``folder`` (both resolved; ``folder`` itself excluded)."""
    return folder.resolve() in path.resolve().parents


def refuse_overwriting_inputs(inputs: Iterable[str | os.PathLike], outputs: Iterable[str | os.PathLike]) -> None:
    """Raise :class:`LdlError` when writing ``outputs`` would replace one of ``inputs``.

    ``outputs`` lists every path a command writes, the files it writes beside its main output
    included (``ldlmap lines`` writes a ``.txt`` beside the ``.obj``); an output that is the same
    file as an input (same resolved path, a symlink or a hard link to it), or a folder the command
    replaces that holds an input, is refused in one line naming both. ``None`` entries are skipped.
    Call it before any work is done.
    """
    ins = [Path(p) for p in inputs if p is not None]
    for out in (Path(p) for p in outputs if p is not None):
        for src in ins:
            if _same_path(out, src):
                raise LdlError(f"output {out} would replace the input {src}; write it elsewhere (another name "
                               "or folder)")
            if _holds(out, src):
                raise LdlError(f"output {out} would replace the folder that holds the input {src}; write it "
                               "elsewhere")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _check_writable_dir(folder: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise LdlError(f"cannot create output folder {folder}: {exc.strerror or exc}") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise LdlError(f"output folder is not writable: {folder}")


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it to ``path`` if the block succeeds.

    The temporary name keeps the extension (or ``suffix``) so that writers which pick a format
    from the extension (open3d, OpenCV) still work.
    """
    target = Path(path)
    _check_writable_dir(target.parent)
    ext = suffix if suffix is not None else "".join(target.suffixes[-1:])
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=".tmp" + ext, dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; outputs get the usual permissions
    try:
        yield tmp
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; move it to ``path`` if the block succeeds.

    Refuses to replace an existing non-empty folder unless ``overwrite`` is set.
    """
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise LdlError(f"output exists and is not a folder: {target}")
    if target.exists() and any(target.iterdir()) and not overwrite:
        raise LdlError(f"output folder is not empty: {target} (use --overwrite to replace it)")
    _check_writable_dir(target.parent)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    try:
        yield tmp
        if target.exists():
            shutil.rmtree(target)
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
