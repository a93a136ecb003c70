"""User-facing errors and atomic outputs.

Library code raises :class:`LdlError` (or a subclass) with a one-line message for anything a
user can fix: missing or corrupt files, bad shapes, NaNs, wrong format versions. The CLIs turn
it into ``error: <message>`` on stderr and exit code 1 (see :func:`ldlmap.core.cli_common.main`).

Outputs are written through :func:`atomic_file` / :func:`atomic_dir`: to a temporary sibling
that is renamed into place only when the ``with`` block succeeds, so a failed or interrupted
command never leaves a half-written file behind. A temporary's name says whose it is
(``.<name>.ldltmp.<host>.<pid>.<random>.tmp<ext>``), and the next write of the same output removes
those of processes that are gone (a run killed with SIGKILL cannot clean up after itself).
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import re
import shutil
import socket
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator


class LdlError(Exception):
    """An error whose message is shown to the user as one line (no traceback)."""


class InputError(LdlError):
    """Missing, unreadable, corrupt or invalid input."""


class FormatVersionError(LdlError):
    """A file written by another (newer or older) format version."""


class WriteError(LdlError, OSError):
    """An output that could not be written (no space left, quota, ...): one line naming the output,
    and still an ``OSError`` (same ``errno``) for callers that treat write failures alike."""

    def __init__(self, message: str, errno_: int | None = None):
        super().__init__(message)
        self.errno, self.strerror = errno_, message

    def __str__(self) -> str:
        return str(self.args[0])


def check_choice(value: str, valid: tuple[str, ...], name: str) -> None:
    """A one-line InputError unless ``value`` is one of ``valid`` (``name``: how the caller calls it)."""
    if value not in valid:
        raise InputError(f"unknown {name} {value!r}; valid: {', '.join(valid)}")


def check_range(value: float | int | None, option: str, lo: float, hi: float, integer: bool = False,
                why: str = "") -> None:
    """Raise a one-line :class:`~ldlmap.core.errors.InputError` unless ``value`` (None passes) is a finite
    number in ``[lo, hi]`` (``why``: what the bound protects, appended to the message); call it
    before any work is done."""
    if value is None:
        return
    if not math.isfinite(value) or not lo <= value <= hi:
        show = (lambda v: str(int(v))) if integer else (lambda v: f"{v:g}")
        got = show(value) if math.isfinite(value) else str(value)
        raise InputError(f"{option} must be {'an integer' if integer else 'a number'} in [{show(lo)}, {show(hi)}], "
                         f"got {got}" + (f" ({why})" if why else ""))


# Write failures said as "<reason> writing PATH" (the reason alone does not say which output failed).
_WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.EROFS}


@contextlib.contextmanager
def naming_output(target: str | os.PathLike) -> Iterator[None]:
    """Turn a write failure (:data:`_WRITE_ERRNOS`: no space left on device, quota, ...) inside the
    block into a :class:`WriteError` naming ``target``: ``no space left on device writing PATH``."""
    try:
        yield
    except WriteError:
        raise
    except OSError as exc:
        if exc.errno not in _WRITE_ERRNOS:
            raise
        why = (exc.strerror or os.strerror(exc.errno)).rstrip(".")
        raise WriteError(f"{why[:1].lower()}{why[1:]} writing {target}", exc.errno) from None


def require_file(path: str | os.PathLike, what: str = "file") -> Path:
    """Return ``path`` as a Path, raising :class:`InputError` when it is not an existing file."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{what} not found: {p}")
    if not p.is_file():
        raise InputError(f"{what} is not a file: {p}")
    return p


def _file_id(p: Path) -> tuple[int, int] | None:
    """(device, inode) of an existing file or folder (hard links share it), else None."""
    try:
        st = p.stat()
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def refuse_overwriting_inputs(inputs: Iterable[str | os.PathLike], outputs: Iterable[str | os.PathLike]) -> None:
    """Raise :class:`LdlError` when writing ``outputs`` would replace one of ``inputs``.

    ``outputs`` lists every path a command writes, the files it writes beside its main output
    included (``ldlmap lines`` writes a ``.txt`` beside the ``.obj``); an output that is the same
    file as an input (same resolved path, a symlink or a hard link to it), or a folder the command
    replaces that holds an input, is refused in one line naming both. ``None`` entries are skipped.
    Call it before any work is done. Each path is resolved once and looked up in sets, so a run's
    thousands of panoramas and pictures cost no pairwise comparison.
    """
    same: dict[Any, Path] = {}  # resolved path or (device, inode) of an input -> the input
    held: dict[Path, Path] = {}  # a folder holding an input -> the input
    for src in (Path(p) for p in inputs if p is not None):
        r = src.resolve()
        same.setdefault(r, src)
        for folder in r.parents:
            held.setdefault(folder, src)
        ident = _file_id(src)
        if ident is not None:
            same.setdefault(ident, src)
    for out in (Path(p) for p in outputs if p is not None):
        r = out.resolve()
        src = same.get(r) or same.get(_file_id(out))
        if src is not None:
            raise LdlError(f"output {out} would replace the input {src}; write it elsewhere (another name "
                           "or folder)")
        if r in held:
            raise LdlError(f"output {out} would replace the folder that holds the input {held[r]}; write it "
                           "elsewhere")


HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def starts_with(path: str | os.PathLike, signature: bytes) -> bool:
    """Whether the file ``path`` begins with ``signature`` (False when unreadable)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(len(signature)) == signature
    except OSError:
        return False


def refuse_replacing_other_files(path: str | os.PathLike, is_ours: Callable[[Path], bool], what: str,
                                 overwrite: bool = False,
                                 remedy: str = "use --overwrite to replace it, or another name") -> None:
    """Raise :class:`LdlError` when ``path`` exists and is not a ``what`` (``is_ours``: one this
    command writes, which a new run replaces as a user expects), unless ``overwrite``. A folder is
    never replaced by a file. ``remedy``: what the message tells the user to do (a command without
    ``--overwrite`` says something else)."""
    p = Path(path)
    if p.is_dir():
        raise LdlError(f"output {p} is a folder; give a file name")
    if p.exists() and not overwrite and not is_ours(p):
        raise LdlError(f"output {p} exists and is not {what}; {remedy}")


def check_writable_output(path: str | os.PathLike, option: str = "output") -> Path:
    """Before any work: refuse (one line naming ``path`` as the user gave it) an output whose folder,
    or the nearest existing folder above it, cannot take a new file (read-only, /proc). Tried by
    creating and removing a temporary file there, which also holds for root and odd filesystems."""
    p = Path(path)
    folder = next((d for d in (p.parent, *p.parent.parents) if d.exists()), Path("."))
    try:
        if not folder.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, "not a folder")
        with tempfile.TemporaryFile(dir=folder, prefix=f".{p.name}.{_TMP_TAG}.probe."):
            pass
    except OSError as exc:
        why = "files cannot be created there" if exc.errno == errno.ENOENT else exc.strerror or str(exc)
        raise LdlError(f"cannot write {option} {p}: {folder} is not a writable folder ({why})") from None
    return p


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


_TMP_TAG = "ldltmp"  # temporary names: .<name>.ldltmp.<host>.<pid>.<random>.tmp<ext> (see _temp_prefix)


def _host() -> str:
    """This machine's name as it may appear in a file name (no separators)."""
    return re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname()) or "host"


def _temp_prefix(name: str) -> str:
    """The start of a temporary sibling's name for the output ``name``: owned by this host and process."""
    return f".{name}.{_TMP_TAG}.{_host()}.{os.getpid()}."


def _process_alive(pid: int) -> bool:
    """Whether a process ``pid`` exists on this machine (one of another user counts as alive)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def remove_stale_temporaries(target: str | os.PathLike, ext: str | None = None) -> list[Path]:
    """Remove the temporary siblings of ``target`` left by killed runs: those named by
    :func:`atomic_file` (``ext``: the temporary's extension) or :func:`atomic_dir` (``ext`` None)
    for the same output, made on this host by a process that no longer exists (never those of a
    live run, nor of another machine). Returns the paths removed."""
    t = Path(target)
    name = t.name if ext is None else t.stem
    pattern = re.compile(rf"^\.{re.escape(name)}\.{_TMP_TAG}\.{re.escape(_host())}\.(\d+)\.[A-Za-z0-9_]+"
                         rf"\.tmp{re.escape(ext or '')}$")
    removed = []
    try:
        siblings = list(t.parent.iterdir())
    except OSError:
        return removed
    for p in siblings:
        m = pattern.match(p.name)
        if m is None or _process_alive(int(m.group(1))):
            continue
        try:
            shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()
            removed.append(p)
        except OSError:
            pass  # removed by another run meanwhile, or not ours to remove: leave it
    return removed


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it to ``path`` if the block succeeds.

    The temporary name keeps the extension (or ``suffix``) so that writers which pick a format
    from the extension (open3d, OpenCV) still work; it names this host and process, and the
    temporaries of ``path`` left by killed runs are removed first (:func:`remove_stale_temporaries`).
    """
    target = Path(path)
    _check_writable_dir(target.parent)
    ext = suffix if suffix is not None else "".join(target.suffixes[-1:])
    remove_stale_temporaries(target, ext)
    fd, tmp_name = tempfile.mkstemp(prefix=_temp_prefix(target.stem), suffix=".tmp" + ext, dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; outputs get the usual permissions
    try:
        with naming_output(target):
            yield tmp
            os.replace(tmp, target)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, overwrite: bool = False,
               commit: Callable[[Path, Path], None] | None = None) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; move it to ``path`` if the block succeeds.

    Refuses to replace an existing non-empty folder unless ``overwrite`` is set. The temporary
    folders of ``path`` left by killed runs are removed first (:func:`remove_stale_temporaries`).
    ``commit(tmp, path)``, when given, moves the contents into place instead of replacing the
    whole folder (``ldlmap synth --overwrite`` keeps the files it did not write).
    """
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise LdlError(f"output exists and is not a folder: {target}")
    if target.exists() and any(target.iterdir()) and not overwrite:
        raise LdlError(f"output folder is not empty: {target} (use --overwrite to replace it)")
    _check_writable_dir(target.parent)
    remove_stale_temporaries(target)
    tmp = Path(tempfile.mkdtemp(prefix=_temp_prefix(target.name), suffix=".tmp", dir=target.parent))
    os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes 0700; outputs get the usual permissions
    try:
        with naming_output(target):
            yield tmp
            if commit is not None:
                commit(tmp, target)
            else:
                if target.exists():
                    shutil.rmtree(target)
                os.replace(tmp, target)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
