"""Helpers shared by the ``ldlmap`` and ``ldlloc`` command-line programs.

Both programs are Typer apps made by :func:`make_app`; its click group turns
:class:`~ldlmap.errors.LdlError` (and ``OSError``) raised anywhere in a command into one line
``error: <message>`` on stderr and exit code 1, both for the installed scripts and for Typer's
``CliRunner`` in tests. Set ``LDL_DEBUG=1`` to get the traceback instead.
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


def fail(message: str, code: int = 1) -> None:
    """Print ``error: message`` as one line on stderr and exit with ``code``."""
    err_console.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


class _ErrorHandlingGroup(TyperGroup):
    def invoke(self, ctx: click.Context):  # noqa: D401 - click API
        from ldlmap.errors import LdlError

        try:
            return super().invoke(ctx)
        except (click.exceptions.Exit, click.ClickException, click.Abort):
            raise
        except LdlError as exc:
            if os.environ.get("LDL_DEBUG") == "1":
                raise
            fail(str(exc))
        except OSError as exc:
            if os.environ.get("LDL_DEBUG") == "1":
                raise
            where = f": {exc.filename}" if getattr(exc, "filename", None) else ""
            fail(f"{exc.strerror or exc}{where}")
        except KeyboardInterrupt:
            fail("interrupted", code=130)


def make_app(name: str, help: str) -> typer.Typer:
    """A Typer app with one-line error reporting and no pretty tracebacks of locals."""
    app = typer.Typer(name=name, help=help, cls=_ErrorHandlingGroup, no_args_is_help=True,
                      add_completion=False, pretty_exceptions_show_locals=False)

    @app.callback()
    def _root() -> None:  # keeps the app a command group even with a single command
        pass

    return app


def ray_option():
    """``--ray ADDRESS`` of the batch commands (``prepare``, ``run``): run on a Ray cluster."""
    return typer.Option(None, "--ray", metavar="ADDRESS",
                        help="Run on a Ray cluster (needs Ray: the toolkit's ray extra, which `make install` "
                             "installs): local (start one on this machine, all cores), local:N (N CPUs), auto (join "
                             "the one started here with `ray start`), HOST:PORT (its head node) or ray://HOST:PORT. "
                             "Inputs and outputs are read and written where the workers run: a shared filesystem "
                             "on several machines.")
