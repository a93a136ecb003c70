"""`ldlmap info` and the one-line error handling shared by both CLIs."""

from __future__ import annotations

from typer.testing import CliRunner

from ldlmap.cli import app
from ldlmap.map.mapfile import write_map
from tests.test_mapfile import make_map

runner = CliRunner()


def test_info_prints_summary(tmp_path):
    p = write_map(tmp_path / "room_1.h5", make_map())
    res = runner.invoke(app, ["info", str(p)])
    assert res.exit_code == 0, res.output
    assert "room_1" in res.output and "sift" in res.output and "35 -> 30" in res.output


def test_info_errors_are_one_line(tmp_path):
    res = runner.invoke(app, ["info", str(tmp_path / "missing.h5")])
    assert res.exit_code == 1
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and "not found" in lines[0]
    bad = tmp_path / "bad.h5"
    bad.write_text("garbage")
    res = runner.invoke(app, ["info", str(bad)])
    assert res.exit_code == 1 and "Traceback" not in res.output


def test_console_scripts_point_at_the_typer_apps():
    """`ldlmap` / `ldlloc` entry points must be the apps, not a command that shares a name."""
    import importlib
    import tomllib
    from pathlib import Path

    import typer

    scripts = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())["project"]["scripts"]
    assert set(scripts) == {"ldlmap", "ldlloc"}
    for target in scripts.values():
        module, attr = target.split(":")
        assert isinstance(getattr(importlib.import_module(module), attr), typer.Typer), target
