"""Shared pytest fixtures.

``demo_dataset`` generates the synthetic demo dataset once for the whole run (also across
pytest-xdist workers, through a lock file in the shared temporary folder) with the real CLIs:
``ldlmap synth --preset demo`` and ``ldlmap prepare`` (SIFT maps).
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

import pytest

os.environ.setdefault("OMP_NUM_THREADS", "1")  # two xdist workers on two cores

DEMO_SEED = 7  # the seed the end-to-end tests pick
DEMO_PER_SPLIT = 5  # panoramas per scene and split: 10 per split over the 2 demo scenes


def _shared_dir(tmp_path_factory) -> Path:
    base = tmp_path_factory.getbasetemp()
    # Under xdist every worker has its own basetemp below a shared parent.
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@pytest.fixture(scope="session")
def demo_dataset(tmp_path_factory) -> Path:
    """Root of a synthetic demo dataset with SIFT maps in ``<root>/maps``."""
    from typer.testing import CliRunner

    from ldlmap.cli import app

    # LDL_TEST_DEMO_DIR keeps the dataset between runs while developing (CI leaves it unset).
    keep = os.environ.get("LDL_TEST_DEMO_DIR")
    shared = Path(keep) if keep else _shared_dir(tmp_path_factory)
    shared.mkdir(parents=True, exist_ok=True)
    root = shared / f"demo_seed{DEMO_SEED}"
    with open(shared / "demo_dataset.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (root / "maps" / "synthroom_2.h5").exists():
            runner = CliRunner()
            res = runner.invoke(app, ["synth", str(root), "--preset", "demo", "--seed", str(DEMO_SEED),
                                      "--per-split", str(DEMO_PER_SPLIT), "--quiet", "--overwrite"])
            assert res.exit_code == 0, res.output
            res = runner.invoke(app, ["prepare", str(root), "--features", "sift"])
            assert res.exit_code == 0, res.output
        fcntl.flock(lock, fcntl.LOCK_UN)
    return root
