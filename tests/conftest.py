"""Shared pytest fixtures and the order in which `make test` hands tests to its two workers.

Session data made once for the whole run (also across pytest-xdist workers, through a lock file
in the shared temporary folder), with the real CLIs:

* ``demo_dataset``: ``ldlmap synth --preset demo`` and ``ldlmap prepare`` (SIFT maps);
* ``tiny_synth``: the demo preset at 64 x 32 pixels, one panorama per split (``ldlmap synth``);

and per worker:

* ``thin_scans``: the demo rooms' scans thinned to a tenth, for builds that check a command's
  wiring rather than a map's accuracy (the full scans' maps are ``demo_dataset``'s);
* ``demo_localized``: every demo query localized on its room's map with the default parameters on
  the CPU (the ``end_to_end`` group's accuracy and device tests judge the same poses).

Schedule (``pytest_collection_modifyitems``): under ``--dist loadgroup`` xdist hands the work
units out in collection order (group-size reordering is turned off in ``pytest_configure``). The
first unit is the ``ray`` group, which needs the demo dataset: its worker generates the dataset
(the largest single piece of work) while the other runs the tests that need no demo data; the
tests on the demo data follow, xdist groups and the slow modules first, so that both workers end
at about the same time.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path
from typing import Callable

import pytest

os.environ.setdefault("OMP_NUM_THREADS", "1")  # two xdist workers on two cores

DEMO_SEED = 7  # the seed the end-to-end tests pick
DEMO_PER_SPLIT = 5  # panoramas per scene and split: 10 per split over the 2 demo scenes
TINY_SEED = 1  # ``tiny_synth``: the seed the synth determinism tests compare against
TINY = ["--width", "64", "--per-split", "1", "--quiet"]  # small panoramas: files and seeds, not images
FIRST_GROUP = "ray"  # the unit that starts the run: it needs the demo dataset (see the module docstring)
# Modules whose demo-data tests take 5-35 CPU seconds each: they run before the quick ones, so
# that neither worker is left with a long test at the end.
DEMO_HEAVY = ("test_learned_features.py", "test_cli_build_run.py", "test_sfm_frame.py", "test_cube_features.py")
DEMO_SCENES = ("synthroom_1", "synthroom_2")


def _shared_dir(tmp_path_factory) -> Path:
    base = tmp_path_factory.getbasetemp()
    # Under xdist every worker has its own basetemp below a shared parent.
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def _made_once(tmp_path_factory, name: str, done: str, make: Callable[[Path], None], keep: str | None = None) -> Path:
    """``<shared>/<name>``, made by ``make`` unless ``<name>/<done>`` exists, under a file lock so
    that the workers make it once; in the folder ``keep`` instead when given (kept between runs)."""
    shared = Path(keep) if keep else _shared_dir(tmp_path_factory)
    shared.mkdir(parents=True, exist_ok=True)
    root = shared / name
    with open(shared / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (root / done).exists():
            make(root)
        fcntl.flock(lock, fcntl.LOCK_UN)
    return root


def _invoke(app, args: list[str]) -> None:
    from typer.testing import CliRunner

    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output


@pytest.fixture(scope="session")
def demo_dataset(tmp_path_factory) -> Path:
    """Root of a synthetic demo dataset with SIFT maps in ``<root>/maps``."""
    from ldlmap.cli import app

    def make(root: Path) -> None:
        _invoke(app, ["synth", str(root), "--preset", "demo", "--seed", str(DEMO_SEED),
                      "--per-split", str(DEMO_PER_SPLIT), "--quiet", "--overwrite"])
        _invoke(app, ["prepare", str(root), "--features", "sift"])

    # LDL_TEST_DEMO_DIR keeps the dataset between runs while developing (CI leaves it unset).
    return _made_once(tmp_path_factory, f"demo_seed{DEMO_SEED}", "maps/synthroom_2.h5", make,
                      keep=os.environ.get("LDL_TEST_DEMO_DIR"))


@pytest.fixture(scope="session")
def tiny_synth(tmp_path_factory) -> Path:
    """``ldlmap synth <root> --preset demo --seed 1 --width 64 --per-split 1`` (read only)."""
    from ldlmap.cli import app

    def make(root: Path) -> None:
        _invoke(app, ["synth", str(root), "--preset", "demo", "--seed", str(TINY_SEED), *TINY, "--overwrite"])

    return _made_once(tmp_path_factory, f"tiny_seed{TINY_SEED}", "dataset.json", make)


@pytest.fixture(scope="session")
def thin_scans(demo_dataset, tmp_path_factory) -> Path:
    """``<root>/pcd/<scene>.ply``: every tenth point of the demo rooms' scans (read only)."""
    from ldlmap.io.pointcloud import read_point_cloud
    from ldlmap.synth.scan import write_ply

    root = tmp_path_factory.mktemp("thin_scans")
    (root / "pcd").mkdir()
    for scene in DEMO_SCENES:
        pc = read_point_cloud(demo_dataset / "pcd" / f"{scene}.ply")
        write_ply(root / "pcd" / f"{scene}.ply", pc.points[::10], pc.colors[::10])
    return root


@pytest.fixture(scope="session")
def demo_localized(demo_dataset) -> dict:
    """query name -> ``(query, Localization)`` for every demo query, localized on its room's map by
    ``Localizer`` with the default parameters on the CPU; the Localization is None where the
    search raised ``LdlError`` (a failed query)."""
    from ldlmap.core.errors import LdlError
    from ldlmap.datasets import open_dataset
    from ldlmap.map.mapfile import read_map
    from ldlloc.pipeline import Localizer, load_image

    ds, out = open_dataset(demo_dataset, "omniscenes"), {}
    for scene in ds.scenes():
        loc = Localizer(read_map(demo_dataset / "maps" / f"{scene}.h5", load_cloud=False))
        for q in ds.queries(scene=scene):
            try:
                out[q.name] = (q, loc.localize(load_image(q.image)))
            except LdlError:
                out[q.name] = (q, None)
    return out


# ------------------------------------------------------------------------------------ schedule


def pytest_configure(config) -> None:
    if hasattr(config.option, "loadscopereorder"):  # xdist: keep the collection order below
        config.option.loadscopereorder = False


def _group(item) -> str | None:
    mark = item.get_closest_marker("xdist_group")
    return (mark.args[0] if mark.args else mark.kwargs.get("name")) if mark else None


def _schedule_rank(item, demo_groups: set[str]) -> tuple[int, int, int]:
    group = _group(item)
    if "demo_dataset" not in item.fixturenames and group not in demo_groups:
        return (1, 0 if group else 1, 0)
    if group == FIRST_GROUP:
        return (0, 0, 0)
    module = item.path.name
    return (2, 0 if group else 1, DEMO_HEAVY.index(module) if module in DEMO_HEAVY else len(DEMO_HEAVY))


def pytest_collection_modifyitems(config, items) -> None:
    # A group is one work unit, handed out where its first test stands: a group with any test on the
    # demo data goes with the demo tests, or its worker would wait for the dataset (idle) meanwhile.
    demo_groups = {_group(item) for item in items if "demo_dataset" in item.fixturenames} - {None}
    items.sort(key=lambda item: _schedule_rank(item, demo_groups))  # stable: file order within each rank
