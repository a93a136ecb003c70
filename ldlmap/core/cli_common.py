"""Helpers shared by the ``ldlmap`` and ``ldlloc`` command-line programs.

Both programs are Typer apps made by :func:`make_app`; its click group turns
:class:`~ldlmap.core.errors.LdlError` (and ``OSError``) raised anywhere in a command into one line
``error: <message>`` on stderr and exit code 1, both for the installed scripts and for Typer's
``CliRunner`` in tests. Any other exception is a bug of ours: one line ``error: internal error
(...)`` and exit code 70. Set ``LDL_DEBUG=1`` to get the traceback instead.
"""

from __future__ import annotations

import os
import sys

import click
import typer
from rich.console import Console
from typer.core import TyperGroup

# When output goes to a file or a CI log, Rich would assume 80 columns and squeeze the tables.
console = Console(width=None if sys.stdout.isatty() or os.environ.get("COLUMNS") else 132)
err_console = Console(stderr=True, width=None if sys.stderr.isatty() or os.environ.get("COLUMNS") else 400)


INTERNAL_ERROR = 70  # EX_SOFTWARE: an exception no check of ours anticipated (a bug to report)


def fail(message: str, code: int = 1, as_json: bool = False) -> None:
    """Print ``error: message`` as one line on stderr (or ``{"error": message}`` on stdout when
    ``as_json``) and exit with ``code``."""
    if as_json:
        import json

        typer.echo(json.dumps({"error": message}))
    else:
        err_console.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def _wants_json(args: list[str]) -> bool:
    """Whether the command line asks for JSON output (``--json`` before any ``--``)."""
    return "--json" in args[:args.index("--")] if "--" in args else "--json" in args


def _usage_error() -> type:
    """Click's UsageError (typer vendors click from 0.16 on; older typer uses click itself)."""
    try:
        from typer._click.exceptions import UsageError
    except ImportError:  # pragma: no cover - older typer
        from click.exceptions import UsageError
    return UsageError


def _control_flow_exceptions() -> tuple[type, ...]:
    """The exceptions click and typer use to end a command (``--help``, ``typer.Exit``, usage
    errors): never reported as errors of ours. Typer 0.16+ vendors click with its own classes."""
    kinds: list[type] = [click.exceptions.Exit, click.ClickException, click.Abort, typer.Exit, typer.Abort]
    try:
        from typer.exceptions import TyperException
    except ImportError:  # pragma: no cover - older typer
        pass
    else:
        kinds.append(TyperException)
    return tuple(kinds)


class _ErrorHandlingGroup(TyperGroup):
    def invoke(self, ctx: click.Context):  # noqa: D401 - click API
        from ldlmap.core.errors import LdlError

        as_json = _wants_json([*getattr(ctx, "_protected_args", []), *ctx.args])
        debug = os.environ.get("LDL_DEBUG") == "1"
        try:
            return super().invoke(ctx)
        except _usage_error() as exc:  # a malformed option: click's message, or JSON with --json
            if not as_json:
                raise
            fail(exc.format_message(), code=exc.exit_code, as_json=True)
        except _control_flow_exceptions():  # --help, exits, usage errors: click's and typer's own
            raise
        except LdlError as exc:
            if debug:
                raise
            fail(str(exc), as_json=as_json)
        except OSError as exc:
            if debug:
                raise
            where = f": {exc.filename}" if getattr(exc, "filename", None) else ""
            fail(f"{exc.strerror or exc}{where}", as_json=as_json)
        except KeyboardInterrupt:
            fail("interrupted", code=130, as_json=as_json)
        except MemoryError:
            if debug:
                raise
            fail("out of memory (the input or an option asks for more than this machine has)", as_json=as_json)
        except Exception as exc:  # a bug of ours: still one line, with its own exit code
            if debug:
                raise
            fail(f"internal error ({type(exc).__name__}: {exc}); please report it, with LDL_DEBUG=1 for the "
                 "traceback", code=INTERNAL_ERROR, as_json=as_json)


_as_script = False  # True in a CLI process (``_ScriptApp.__call__``), False under CliRunner (tests)


class _ScriptApp(typer.Typer):
    """A Typer app that, run as a script (``app()``: the console scripts, ``python3 -m``), moves
    every object alive at the end into the garbage collector's permanent generation: interpreter
    exit then skips a full collection over the million objects torch's import creates
    (docs/measurements.md#gc-freeze). ``CliRunner`` (tests) does not go through ``__call__``."""

    def __call__(self, *args, **kwargs):
        global _as_script
        _as_script = True
        try:
            return super().__call__(*args, **kwargs)
        finally:
            import gc

            gc.freeze()


def import_heavy(*modules: str) -> None:
    """Import ``modules`` (torch, cv2, h5py) with the cyclic garbage collector paused: torch's import
    allocates about a million objects and would trigger full collections over them
    (docs/measurements.md#gc-freeze). In a CLI process the objects are then frozen (``gc.freeze``),
    so later collections skip them too; under CliRunner (tests) nothing is frozen."""
    import gc
    import importlib

    was_enabled = gc.isenabled()
    gc.disable()
    try:
        for name in modules:
            importlib.import_module(name)
    finally:
        if was_enabled:
            gc.enable()
    if _as_script:
        gc.freeze()


def make_app(name: str, help: str) -> typer.Typer:
    """A Typer app with one-line error reporting and no pretty tracebacks of locals."""
    app = _ScriptApp(name=name, help=help, cls=_ErrorHandlingGroup, no_args_is_help=True,
                     add_completion=False, pretty_exceptions_show_locals=False)

    @app.callback()
    def _root() -> None:  # keeps the app a command group even with a single command
        pass

    return app


def check_range(value: float | int | None, option: str, lo: float, hi: float, integer: bool = False,
                why: str = "") -> None:
    """Raise a one-line :class:`~ldlmap.core.errors.InputError` unless ``value`` (None passes) is a finite
    number in ``[lo, hi]`` (``why``: what the bound protects, appended to the message); call it
    before any work is done."""
    import math

    from ldlmap.core.errors import InputError

    if value is None:
        return
    if not math.isfinite(value) or not lo <= value <= hi:
        show = (lambda v: str(int(v))) if integer else (lambda v: f"{v:g}")
        got = show(value) if math.isfinite(value) else str(value)
        raise InputError(f"{option} must be {'an integer' if integer else 'a number'} in [{show(lo)}, {show(hi)}], "
                         f"got {got}" + (f" ({why})" if why else ""))


def check_device(device: str, option: str = "--device", local: bool = True) -> str:
    """``cpu``, or ``cuda`` / ``cuda:N`` (checked before any work); with ``local`` (the work runs
    here, not on a Ray cluster) torch must see that GPU."""
    import re

    from ldlmap.core.errors import InputError

    m = re.fullmatch(r"cuda(?::(\d{1,3}))?", device)
    if device == "cpu" or (m is not None and not local):
        return device
    if m is None:
        raise InputError(f"{option} must be cpu, cuda or cuda:N, got {device!r}")
    import_heavy("torch")
    import torch

    count = torch.cuda.device_count() if torch.cuda.is_available() else 0
    index = int(m.group(1) or 0)
    if index >= count:
        raise InputError(f"{option} {device}: " + ("CUDA is not available here (no GPU, or torch built without "
                                                   "CUDA); use --device cpu" if count == 0 else
                                                   f"this machine has {count} CUDA GPU(s)"))
    return device


def ray_option():
    """``--ray ADDRESS`` of the batch commands (``prepare``, ``run``): run on a Ray cluster."""
    return typer.Option(None, "--ray", metavar="ADDRESS",
                        help="Run on a Ray cluster (needs Ray: the toolkit's ray extra, which `make install` "
                             "installs): local (start one on this machine, all cores), local:N (N CPUs), auto (join "
                             "the one started here with `ray start`), HOST:PORT (its head node) or ray://HOST:PORT. "
                             "Inputs and outputs are read and written where the workers run: a shared filesystem "
                             "on several machines.")
