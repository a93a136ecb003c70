"""SIGTERM ends a command as Ctrl-C does: the exception unwinds through the same clean-ups (results
files keep every finished query, temporaries are removed) and the CLI says one line.

pycolmap installs glog's failure-signal handler when it is imported, which answers SIGTERM with a
native stack dump; :func:`import_pycolmap` imports it and puts the Python-level handler back.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from typing import Iterator


class Terminated(KeyboardInterrupt):
    """Raised in the main thread on SIGTERM (a KeyboardInterrupt, so every Ctrl-C clean-up runs)."""


def _raise_terminated(signum, frame) -> None:
    raise Terminated()


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """While the block runs (in the main thread), SIGTERM raises :class:`Terminated`; the previous
    handler is restored after."""
    if not _in_main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)


def restore_sigterm() -> None:
    """Reinstall the Python-level SIGTERM handler over a native one a library installed behind
    Python's back (glog's, at pycolmap's import); without one, the default (end, no dump)."""
    if not _in_main_thread():
        return
    current = signal.getsignal(signal.SIGTERM)
    signal.signal(signal.SIGTERM, current if current is not None else signal.SIG_DFL)


def import_pycolmap():
    """``import pycolmap`` without its SIGTERM stack dump (see the module docstring)."""
    import pycolmap  # here: the handler it installs is replaced right after the import

    restore_sigterm()
    return pycolmap
