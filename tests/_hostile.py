"""Shared checks of the hostile-input tests: a bad input or option ends in one line
``error: ...``, exit code 1 (never the internal-error code 70, never a traceback) and leaves no
output behind."""

from __future__ import annotations

from pathlib import Path


def error_line(res, code: int = 1) -> str:
    """The single ``error:`` line of a CliRunner result that failed with ``code``."""
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert res.exit_code == code, res.output
    assert "Traceback" not in res.output
    assert len(lines) == 1 and lines[0].startswith("error:"), res.output
    return lines[0]


def snapshot(root: Path) -> dict[str, tuple[int, int]]:
    """Every file and folder under ``root`` with its size and modification time (ns)."""
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns) for p in sorted(root.rglob("*"))}


def assert_clean_failure(res, root: Path, before: dict, code: int = 1) -> str:
    """``res`` failed with one error line and nothing under ``root`` changed since ``before``
    (no output left behind, no input touched, no temporary file)."""
    line = error_line(res, code)
    after = snapshot(root)
    assert after == before, (line, sorted(set(after) ^ set(before)) or "a file changed")
    return line
