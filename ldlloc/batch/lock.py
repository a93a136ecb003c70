"""The lock file of a results file (``r.json`` -> ``r.json.lock``), held while a run writes it.

A run takes an exclusive ``flock`` on it, so a second run on the same file is refused at once
(:class:`ResultsBusy`). The file is removed afterwards only when it is ours: made by this run, or
left by a killed one (it holds :data:`LOCK_MARK`); a user's own file of that name is locked but
never written or removed.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

from ldlmap.core.errors import LdlError

LOCK_MARK = b"ldlloc run lock\n"  # what a lock file made by a run holds (only such a file is removed)


def lock_path(path: str | Path) -> Path:
    """The lock file of results file ``path`` (``r.json`` -> ``r.json.lock``), held while a run writes it."""
    p = Path(path)
    return p.with_name(p.name + ".lock")


class ResultsBusy(LdlError):
    """Another run holds the lock of the results file."""


def acquire_lock(path: Path) -> tuple[int, bool]:
    """An open, exclusively locked (``flock``) lock file of results file ``path``, and whether it is
    ours to remove afterwards: made by this run, or left by a killed one (it holds :data:`LOCK_MARK`);
    a user's own file of that name is locked but never written or removed. Refuses at once
    (:class:`ResultsBusy`) when another run holds it."""
    lock = lock_path(path)
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise LdlError(f"cannot create output folder {lock.parent}: {exc.strerror or exc}") from None
    while True:
        try:
            fd, made = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o666), True
            os.write(fd, LOCK_MARK)
        except FileExistsError:
            try:
                fd, made = os.open(lock, os.O_RDONLY), False
            except FileNotFoundError:
                continue  # removed by a run that just finished: make it anew
            except OSError as exc:
                raise LdlError(f"cannot open {lock}: {exc.strerror or exc}") from None
        except OSError as exc:
            raise LdlError(f"cannot write beside {path}: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise ResultsBusy(f"another `ldlloc run` is writing {path} (it holds {lock.name}); wait for it to "
                              "finish or use another --output") from None
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino  # not removed by a run that just finished
        except FileNotFoundError:
            same = False
        if same:
            return fd, made or os.pread(fd, len(LOCK_MARK) + 1, 0) == LOCK_MARK
        os.close(fd)


def release_lock(fd: int, ours: bool, lock: Path) -> None:
    """Unlock; remove the lock file only when it is ours (:func:`acquire_lock`)."""
    if ours:
        try:
            lock.unlink()  # while still holding it: a run that opened the old file retries on a new one
        except OSError:
            pass
    os.close(fd)
