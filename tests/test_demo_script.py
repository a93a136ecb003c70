"""`make demo` / scripts/demo.sh run the programs with the interpreter given as PYTHON, never
whatever `ldlmap` or `ldlloc` is first on PATH."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# A stand-in interpreter: records each call, and for `synth` writes the panorama the demo looks for.
FAKE_PYTHON = """#!/bin/sh
echo "$*" >> "{log}"
if [ "$3" = "synth" ]; then
  mkdir -p "$4/extreme_pano/extreme_synthroom_1_scene_1" && : > "$4/extreme_pano/extreme_synthroom_1_scene_1/0000.jpg"
fi
"""


def _fake_python(tmp_path: Path) -> tuple[Path, Path]:
    log = tmp_path / "calls.log"
    fake = tmp_path / "bin" / "fakepython"
    fake.parent.mkdir()
    fake.write_text(FAKE_PYTHON.format(log=log))
    fake.chmod(0o755)
    return fake, log


def _decoys(tmp_path: Path) -> Path:
    """A PATH folder whose `ldlmap` and `ldlloc` fail loudly: the demo must not run them."""
    decoy = tmp_path / "decoy"
    decoy.mkdir()
    for name in ("ldlmap", "ldlloc"):
        (decoy / name).write_text("#!/bin/sh\necho \"decoy $0 ran\" >&2\nexit 9\n")
        (decoy / name).chmod(0o755)
    return decoy


def _check_calls(log: Path, out: Path) -> None:
    calls = log.read_text().splitlines()
    assert [c.split()[:3] for c in calls] == [
        ["-m", "ldlmap.cli", "synth"], ["-m", "ldlmap.cli", "prepare"], ["-m", "ldlmap.cli", "info"],
        ["-m", "ldlloc.cli", "localize"], ["-m", "ldlloc.cli", "run"]]
    assert calls[0].split()[3] == str(out / "data")


def test_demo_script_runs_the_programs_with_the_given_python(tmp_path):
    fake, log = _fake_python(tmp_path)
    env = {**os.environ, "PYTHON": str(fake), "PATH": f"{_decoys(tmp_path)}{os.pathsep}{os.environ['PATH']}"}
    out = tmp_path / "demo"
    r = subprocess.run(["bash", str(ROOT / "scripts" / "demo.sh"), str(out)], env=env, capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "decoy" not in r.stderr
    _check_calls(log, out)


def test_make_demo_passes_its_python_to_the_script(tmp_path):
    make = shutil.which("make")
    if make is None:
        pytest.skip("make is not installed")
    fake, log = _fake_python(tmp_path)
    env = {**os.environ, "PATH": f"{_decoys(tmp_path)}{os.pathsep}{os.environ['PATH']}"}
    env.pop("PYTHON", None)
    out = tmp_path / "demo"
    r = subprocess.run([make, "-s", "-C", str(ROOT), "demo", f"PYTHON={fake}", f"DEMO_DIR={out}"], env=env,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "decoy" not in r.stderr
    _check_calls(log, out)
