"""``ldlmap prepare --ray``: one Ray task per scene map (:func:`prepare_dataset_ray`).

Each task runs :func:`ldlmap.batch.prepare.prepare_dataset` for its one scene, where the worker runs:
the same up-to-date check, the same builder, the same atomic write, so the maps are the plain
path's byte for byte. Inputs are read and maps written on the workers' filesystem (a shared
filesystem on a multi-node cluster: the same paths everywhere).

Faults: a worker process that dies mid-build is retried by Ray (:data:`ldlmap.batch.ray_cluster.RETRIES`
times); a scene whose input is bad fails in its task like in the plain path (``failed`` with
its reason) and the others go on; a task that raised anything else, or whose worker died past
its retries, is recorded ``failed`` with the reason. Ctrl-C cancels the outstanding tasks (a
build interrupted in a worker removes its temporary file) and re-raises.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable

from ldlmap.batch.prepare import SceneOutcome, prepare_dataset
from ldlmap.batch.ray_cluster import (RETRIES, TaskDone, WorkerInfo, as_completed, check_resources, current_worker,
                                      enter_folder, failure_reason, ray_session, stop)
from ldlmap.core.cli_common import set_threads
from ldlmap.core.errors import InputError
from ldlmap.datasets import open_dataset
from ldlmap.map.params import BuildParams


def build_scene(cwd: str, root: str, kind: str, maps_dir: str | None, params: BuildParams | None, scene: str,
                options: dict[str, Any], threads: int = 1) -> tuple[SceneOutcome, WorkerInfo]:
    """The Ray task: build (or skip) one scene's map with the plain path, in the driver's folder
    ``cwd``, with ``threads`` CPU threads (0: one per core); where it ran."""
    enter_folder(cwd)
    set_threads(threads)
    (outcome,) = prepare_dataset(root, kind, maps_dir, params, scenes=[scene], **options)
    return outcome, current_worker()


def prepare_dataset_ray(root: str | Path, kind: str | None, maps_dir: str | Path | None = None,
                        params: BuildParams | None = None, scenes: list[str] | None = None,
                        progress: Callable[[TaskDone], None] | None = None, address: str = "local",
                        threads: int = 1, **options: Any) -> list[SceneOutcome]:
    """:func:`ldlmap.batch.prepare.prepare_dataset` on a Ray cluster (``address``: see
    :data:`ldlmap.batch.ray_cluster.ADDRESS_HELP`), one task per scene. ``options`` are passed on to
    ``prepare_dataset`` (``overwrite``, ``use_line_files``, ``map_level``, ...). Outcomes come back
    in the plain path's scene order; ``progress`` gets a :class:`TaskDone` per finished scene.
    ``threads``: CPU threads (and Ray CPUs) per task, as ``--threads`` (0: one per core, one Ray CPU)."""
    ds = open_dataset(root, kind, **({"map_level": options["map_level"]} if "map_level" in options else {}))
    todo = list(scenes) if scenes else ds.scenes()
    unknown = sorted(set(todo) - set(ds.scenes()))
    if unknown:
        raise InputError(f"unknown scene(s) {', '.join(unknown)}; available: {', '.join(ds.scenes())}")
    maps_root = Path(maps_dir) if maps_dir is not None else Path(ds.root) / "maps"
    device = params.device if params is not None else "cpu"
    with ray_session(address) as ray:
        task = ray.remote(build_scene).options(**check_resources(ray, device, max(1, threads)), max_retries=RETRIES)
        maps_arg = None if maps_dir is None else str(maps_dir)
        refs: dict = {}
        outcomes: dict[str, SceneOutcome] = {}
        try:
            for scene in todo:
                refs[task.remote(os.getcwd(), str(ds.root), ds.kind, maps_arg, params, scene, options, threads)] = scene
            for batch in as_completed(list(refs)):
                for ref, value, exc in batch:
                    scene = refs[ref]
                    outcome, worker = value if exc is None else (
                        SceneOutcome(scene, maps_root / f"{scene}.h5", "failed", failure_reason(exc)), None)
                    outcomes[scene] = outcome
                    if progress:
                        progress(TaskDone(f"{scene} {outcome.status}", worker, len(outcomes), len(todo)))
        except BaseException:  # Ctrl-C (KeyboardInterrupt) included: stop the cluster's work
            stop([r for r, s in refs.items() if s not in outcomes])
            raise
    return [outcomes[s] for s in todo]
