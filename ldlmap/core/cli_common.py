"""Helpers shared by the ``ldlmap`` and ``ldlloc`` command-line programs.

Both programs are Typer apps made by :func:`make_app`; its click group turns
:class:`~ldlmap.core.errors.LdlError` (and ``OSError``) raised anywhere in a command into one line
``error: <message>`` on stderr and exit code 1, both for the installed scripts and for Typer's
``CliRunner`` in tests. Any other exception is a bug of ours: one line ``error: internal error
(...)`` and exit code 70. Set ``LDL_DEBUG=1`` to get the traceback instead. A reader of stdout that
leaves early (``| head``) ends the program quietly with exit code 141; ``--version`` prints the
installed version.
"""

from __future__ import annotations

import gc
import importlib
import io
import json
import os
import re
import sys
import typing
from importlib.metadata import PackageNotFoundError, version

import click
import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from typer.core import TyperCommand, TyperGroup

from ldlmap.core.errors import InputError, LdlError, check_range  # noqa: F401 (check_range: the CLIs' import)
from ldlmap.core.lazy import lazy_module
from ldlmap.core.signals import Terminated, sigterm_as_interrupt

cv2 = lazy_module("cv2")
datasets = lazy_module("ldlmap.datasets")
threadpoolctl = lazy_module("threadpoolctl")
torch = lazy_module("torch")

INTERNAL_ERROR = 70  # EX_SOFTWARE: an exception no check of ours anticipated (a bug to report)
BROKEN_PIPE = 141  # 128 + SIGPIPE: what the shell reports for a program whose reader left (`| head`)
DISTRIBUTION = "ldl-toolkit"  # the package both programs come from (pyproject.toml), for --version


def exit_broken_pipe() -> None:
    """Stop quietly because stdout's reader is gone (``ldlloc report r.json | head``): no message,
    exit code :data:`BROKEN_PIPE`. stdout is pointed at /dev/null first, so Python's own flush at
    exit does not fail again and print "Exception ignored"."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError, AttributeError, io.UnsupportedOperation):  # no file descriptor (CliRunner)
        pass
    raise SystemExit(BROKEN_PIPE)


def _console_on_broken_pipe(self: Console) -> None:
    """Rich's ``Console.on_broken_pipe`` in a CLI process: :func:`exit_broken_pipe` (Rich's exits 1)."""
    self.quiet = True
    exit_broken_pipe()


# When output goes to a file or a CI log, Rich would assume 80 columns and squeeze the tables.
console = Console(width=None if sys.stdout.isatty() or os.environ.get("COLUMNS") else 132)
err_console = Console(stderr=True, width=None if sys.stderr.isatty() or os.environ.get("COLUMNS") else 400)


def fail(message: str, code: int = 1, as_json: bool = False) -> None:
    """Print ``error: message`` as one line on stderr (or ``{"error": message}`` on stdout when
    ``as_json``) and exit with ``code``."""
    if as_json:
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


# Metavars of option values by their Python type: upper case, as click writes them.
_TYPE_METAVARS = {"str": "TEXT", "int": "INTEGER", "float": "FLOAT", "Path": "PATH", "PosixPath": "PATH",
                  "text": "TEXT", "integer": "INTEGER", "path": "PATH"}


def _value_type_name(param) -> str:
    """The Python (typer 0.16+) or click type name of a parameter's value (a list's element)."""
    desc = getattr(param, "type_descriptor", None)
    if desc is None:  # pragma: no cover - older typer: click parameter types
        return getattr(getattr(param, "type", None), "name", "text")
    ann = desc.annotation
    if typing.get_origin(ann) is list:
        ann = typing.get_args(ann)[0]
    return getattr(ann, "__name__", str(ann))


def tidy_metavar(param) -> None:
    """Give ``param`` the help placeholder the toolkit uses everywhere (in place, once): an
    argument its upper-case name (MAP, INPUT, ROOT), a flag none (typer 0.16+ writes ``<bool>``),
    an option's value its upper-case type (PATH, TEXT, INTEGER, FLOAT); a metavar set by the
    command (MIN:MAX, ADDRESS) stays."""
    if getattr(param, "_ldl_tidy", False):
        return
    param._ldl_tidy = True
    name = _value_type_name(param)
    value = _TYPE_METAVARS.get(name, name.upper())
    if param.param_type_name == "argument":
        param.metavar = param.metavar or param.name.upper()
        param.display_type_rich = lambda ctx: value  # the type column: PATH, not <path>
    elif param.metavar is None:
        param.metavar = "" if getattr(param, "is_flag", False) else value


def _usage_pieces(command: click.Command, ctx: click.Context) -> list[str]:
    """The usage line after the command name, as click writes it: ``[OPTIONS] MAP [ROOT]``
    (typer 0.16+ writes required arguments in braces, ``{MAP}``)."""
    pieces = [command.options_metavar] if command.options_metavar else []
    for param in command.get_params(ctx):
        if param.param_type_name == "argument":
            name = param.metavar + ("..." if param.nargs != 1 else "")
            pieces.append(name if param.required else f"[{name}]")
    return pieces


class _Command(TyperCommand):
    """A command whose help names its parameters as every other command does
    (:func:`tidy_metavar`, :func:`_usage_pieces`)."""

    def get_params(self, ctx: click.Context) -> list:
        params = super().get_params(ctx)
        for param in params:
            tidy_metavar(param)
        return params

    def collect_usage_pieces(self, ctx: click.Context) -> list[str]:
        return _usage_pieces(self, ctx)


class _ErrorHandlingGroup(TyperGroup):
    def get_params(self, ctx: click.Context) -> list:
        params = super().get_params(ctx)
        for param in params:
            tidy_metavar(param)
        return params

    def make_context(self, *args, **kwargs) -> click.Context:
        """Click's, ending quietly when the program's own ``--help`` meets a broken pipe."""
        try:
            return super().make_context(*args, **kwargs)
        except BrokenPipeError:
            exit_broken_pipe()

    def invoke(self, ctx: click.Context):  # noqa: D401 - click API
        as_json = _wants_json([*getattr(ctx, "_protected_args", []), *ctx.args])
        debug = os.environ.get("LDL_DEBUG") == "1"
        try:
            with sigterm_as_interrupt():  # SIGTERM: as Ctrl-C, then "terminated" (exit 143)
                return super().invoke(ctx)
        except BrokenPipeError:  # the reader of stdout left (`| head`): not an error of the input
            exit_broken_pipe()
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
        except Terminated:
            fail("terminated", code=143, as_json=as_json)
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

    def command(self, *args, cls=None, **kwargs):
        """``Typer.command`` making :class:`_Command` commands (consistent help pages)."""
        return super().command(*args, cls=cls or _Command, **kwargs)

    def __call__(self, *args, **kwargs):
        global _as_script
        _as_script = True
        for stream in (sys.stdout, sys.stderr):  # a file name that is not UTF-8 is printed as \udcff, not a crash
            if hasattr(stream, "reconfigure"):
                stream.reconfigure(errors="backslashreplace")
        Console.on_broken_pipe = _console_on_broken_pipe  # every Rich console of the program: ours and the help's
        try:
            return super().__call__(*args, **kwargs)
        finally:
            gc.freeze()
            try:  # what is still buffered, now: at interpreter exit a broken pipe would print a warning
                sys.stdout.flush()
            except BrokenPipeError:
                exit_broken_pipe()


def import_heavy(*modules: str) -> None:
    """Import ``modules`` (torch, cv2, h5py) with the cyclic garbage collector paused: torch's import
    allocates about a million objects and would trigger full collections over them
    (docs/measurements.md#gc-freeze). In a CLI process the objects are then frozen (``gc.freeze``),
    so later collections skip them too; under CliRunner (tests) nothing is frozen."""
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


def package_version() -> str:
    """The installed toolkit's version (its distribution's metadata), or "unknown" when it is not installed."""
    try:
        return version(DISTRIBUTION)
    except PackageNotFoundError:
        return "unknown"


def make_app(name: str, help: str) -> typer.Typer:
    """A Typer app with one-line error reporting, ``--version`` and no pretty tracebacks of locals."""
    app = _ScriptApp(name=name, help=help, cls=_ErrorHandlingGroup, no_args_is_help=True,
                     add_completion=False, pretty_exceptions_show_locals=False)

    def show_version(value: bool) -> None:
        if value:
            typer.echo(f"{name} {package_version()}")
            raise typer.Exit()

    @app.callback()
    def _root(version: bool = typer.Option(False, "--version", is_eager=True, callback=show_version,
                                           help="Print the program's version and exit.")) -> None:
        """The program itself (a command group even with a single command)."""

    return app


def check_device(device: str, option: str = "--device", local: bool = True) -> str:
    """``cpu``, or ``cuda`` / ``cuda:N`` (checked before any work); with ``local`` (the work runs
    here, not on a Ray cluster) torch must see that GPU."""
    m = re.fullmatch(r"cuda(?::(\d{1,3}))?", device)
    if device == "cpu" or (m is not None and not local):
        return device
    if m is None:
        raise InputError(f"{option} must be cpu, cuda or cuda:N, got {device!r}")
    import_heavy("torch")
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


MAX_THREADS = 1024  # --threads above this is a typo (100000 made torch segfault)
DEFAULT_THREADS = 1  # the work is many small tensor steps: more threads spin and wait (docs/measurements.md)


def threads_option():
    """``--threads N`` of ``build``, ``prepare``, ``localize`` and ``run``: CPU threads of torch and OpenCV."""
    return typer.Option(DEFAULT_THREADS, "--threads", metavar="N",
                        help="CPU threads for torch and OpenCV (default 1: the work is many small steps, which "
                             "more threads slow down on a shared machine; 0: one per core).")


def check_threads(threads: int) -> int:
    """``--threads`` within 0..:data:`MAX_THREADS`, checked before any work."""
    check_range(threads, "--threads", 0, MAX_THREADS, integer=True, why="0: one per core")
    return threads


def set_threads(threads: int) -> None:
    """Use ``threads`` CPU threads in torch, OpenCV and the BLAS and OpenMP pools that numpy and
    scipy use (0: their defaults, one per core)."""
    if check_threads(threads):
        import_heavy("torch", "cv2")
        torch.set_num_threads(threads)
        cv2.setNumThreads(threads)
        threadpoolctl.threadpool_limits(threads)  # numpy's and scipy's BLAS and OpenMP pools (else one thread per core)


# What the screen says while a build stage runs (stages of ldlmap.map.build), and what its steps count.
STAGE_NAMES = {"load": "reading the input", "lines": "3D lines", "principal": "principal directions",
               "translations": "candidate translations", "visibility": "line visibility",
               "fields": "distance fields", "features": "features", "write": "writing the map"}
STAGE_STEPS = {"fields": "translations", "features": "views"}


class StageProgress:
    """The live progress of `ldlmap build` and `prepare`: a row for the whole job (its scenes, its
    time) and a row for the stage running now, named as it starts, with its own timer and, for
    the stages that count them, its steps (distance fields: translations; features: views)."""

    def __init__(self, out: Console, title: str, total: int | None = None, unit: str = ""):
        self.bar = Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[count]}"),
                            TimeElapsedColumn(), console=out, transient=True)
        self.title, self.total, self.unit = title, total, unit
        self.current: tuple[str, str] | None = None  # (label, stage) shown on the stage row

    def __enter__(self) -> "StageProgress":
        self.bar.__enter__()
        self.job = self.bar.add_task(self.title, total=self.total, count=self._count(0, self.total, self.unit))
        self.stage_row = self.bar.add_task("starting", total=None, count="")
        return self

    def __exit__(self, *exc) -> None:
        self.bar.__exit__(*exc)

    @staticmethod
    def _count(done: int, total: int | None, unit: str) -> str:
        return f"{done}/{total} {unit}".rstrip() if total else ""

    def stage(self, label: str, stage: str, done: int, total: int) -> None:
        """A build's ``progress(stage, done, total)`` event (``done = 0``: the stage starts), shown
        as ``label: stage``; a new stage restarts the stage row's timer."""
        counted = total if total > 1 else None  # a stage without steps: a pulsing bar, no count
        count = self._count(done, counted, STAGE_STEPS.get(stage, ""))
        if (label, stage) != self.current:
            self.current = (label, stage)
            self.bar.reset(self.stage_row, total=counted, completed=done if counted else 0, count=count,
                           description=f"{label}: {STAGE_NAMES.get(stage, stage)}")
        elif counted:
            self.bar.update(self.stage_row, completed=done, total=counted, count=count)

    def job_done(self, completed: int, total: int | None = None) -> None:
        """The job row: ``completed`` of its ``total`` items (scenes) done."""
        total = total if total is not None else self.total
        self.bar.update(self.job, completed=completed, total=total, count=self._count(completed, total, self.unit))


DATASET_HELP = ("omniscenes | synthetic (written by `ldlmap synth`) | stanford | zind (default: detected from the "
                "layout).")


def open_dataset_root(root, dataset: str | None, give_root: str, **kwargs):
    """``open_dataset`` for `prepare` and `run`: ``--dataset synthetic`` is read by the OmniScenes
    reader (the layout `ldlmap synth` writes); without a root the kind's default folder is used,
    and when it is not there one line says how to give one (``give_root``: ``ldlmap prepare
    ROOT``, ``ldlloc run --root ROOT``)."""
    if dataset is not None and dataset not in (*datasets.DATASET_KINDS, "synthetic"):
        raise InputError(f"unknown --dataset {dataset!r}; choose one of {', '.join((*datasets.DATASET_KINDS, 'synthetic'))}")
    kind = "omniscenes" if dataset == "synthetic" else dataset
    if root is None:
        kind = kind or "omniscenes"
        default = datasets.DEFAULT_ROOTS[kind]
        if not default.exists():
            raise InputError(f"no dataset root given and the default one, {default}, is not there: give it as "
                             f"`{give_root}` (see datasets/README.md)")
    return datasets.open_dataset(root, kind, **kwargs)


def refuse_map_level(map_level: str | None, kind: str, label: str, root) -> None:
    """One line when ``--map-level`` is given for a dataset other than ZInD (the only one with
    map levels), instead of ignoring it."""
    if map_level is not None and kind != "zind":
        raise InputError(f"--map-level is for ZInD roots (room or floor maps); {root} is a {label} root, with one "
                         "map per scene: leave --map-level out")


def dataset_label(ds) -> str:
    """The dataset kind users see: ``synthetic`` for a dataset of `ldlmap synth`, else its kind."""
    return getattr(ds, "label", ds.kind)
