"""Both programs: ``--version``, and output piped into a reader that leaves early (``| head``)
ends quietly with the shell's SIGPIPE code (141), never ``error: Broken pipe`` and exit 1."""

from __future__ import annotations

import os
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ldlloc.cli import app as loc_app
from ldlmap.cli import app as map_app
from ldlmap.core.cli_common import BROKEN_PIPE, make_app

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("app, name", [(map_app, "ldlmap"), (loc_app, "ldlloc")])
def test_version_names_the_program_and_the_installed_package(app, name):
    r = CliRunner().invoke(app, ["--version"])
    assert r.exit_code == 0, r.output
    assert r.output.strip() == f"{name} {version('ldl-toolkit')}"
    helped = CliRunner().invoke(app, ["--help"])
    assert "--version" in helped.output


def _closed_pipe_run(args: list[str]) -> subprocess.CompletedProcess:
    """``python -m ARGS`` writing to a pipe whose reader is already gone."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    try:
        return subprocess.run([sys.executable, "-m", *args], stdout=write_end, stderr=subprocess.PIPE,
                              cwd=ROOT, env=env, timeout=120)
    finally:
        os.close(write_end)


@pytest.mark.parametrize("args", [
    ["ldlmap.cli", "--help"],  # the program's help (Rich, before any command)
    ["ldlloc.cli", "--help"],
    ["ldlmap.cli", "build", "--help"],  # a command's help (inside the group's invoke)
    ["ldlloc.cli", "--version"],  # plain echo
])
def test_a_reader_that_left_ends_the_program_quietly(args):
    r = _closed_pipe_run(args)
    assert r.returncode == BROKEN_PIPE == 141, (r.returncode, r.stderr)
    assert r.stderr.decode() == ""


def test_broken_pipe_inside_a_command_is_no_error_line():
    """A command whose output write fails with EPIPE (``typer.echo`` of a long result): exit 141,
    nothing on stderr; other OSErrors still give their one line."""
    app = make_app("prog", "A test program.")

    @app.command()
    def talk(kind: str) -> None:
        if kind == "pipe":
            raise BrokenPipeError(32, "Broken pipe")
        raise PermissionError(13, "Permission denied", "out.txt")

    r = CliRunner().invoke(app, ["talk", "pipe"])
    assert r.exit_code == 141 and r.output == "", r.output
    r = CliRunner().invoke(app, ["talk", "other"])
    assert r.exit_code == 1 and "error: Permission denied: out.txt" in r.output
