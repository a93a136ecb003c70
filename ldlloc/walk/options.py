"""The checks of ``ldlloc run``'s walk options (one-line errors, before anything is read)."""

from __future__ import annotations

from typing import Any

from ldlmap.core.errors import InputError
from ldlloc.walk.order import check_order


def check_walk_options(walk: bool, order: str | None, images, ray, save_vis, video=None, fps: float | None = None,
                       every: int | None = None, resume: bool = False, maps=None,
                       dataset_options: dict[str, Any] | None = None, lag: int | None = None) -> None:
    """``--order`` goes with ``--walk --images`` and is one of :data:`~ldlloc.walk.order.ORDERS`; ``--lag``
    (frames, >= 1) goes with ``--walk`` or ``--video``; walks run on Ray one walk per actor, so only
    a dataset's walks (``--root ... --walk``: one per scene) and videos (one walk each) do, never the
    one walk of ``--images --walk``; a walk writes no pictures; ``--fps`` and ``--every`` go with ``--video``, which runs
    alone (no dataset or images; ``dataset_options``: the dataset run's other options by name, e.g.
    ``--split``) and needs ``--maps``."""
    if order is not None and not walk:
        raise InputError("--order goes with --walk")
    if order is not None:
        check_order(order, "--order")
    if order is not None and images is None:
        raise InputError("--order goes with --images (a dataset knows its walks' order)")
    if lag is not None and not (walk or video is not None):
        raise InputError("--lag goes with --walk or --video")
    if lag is not None and lag < 1:
        raise InputError(f"--lag must be a whole number of frames >= 1, got {lag}")
    if ray is not None and walk and images is not None:
        raise InputError("--images --walk is one walk, localized in this process: drop --ray (Ray runs many walks, "
                         "one per actor: --root ... --walk, --video)")
    if (walk or video is not None) and save_vis is not None:
        raise InputError(f"{'--walk' if walk else '--video'} writes no pictures: drop --save-vis")
    if video is None and (fps is not None or every is not None):
        raise InputError(f"{'--fps' if fps is not None else '--every'} goes with --video")
    if video is not None:
        given = [o for o, v in (("--images", images), *(dataset_options or {}).items(), ("--walk", walk)) if v]
        if given:
            raise InputError(f"--video runs alone: drop {', '.join(given)}")
        if maps is None:
            raise InputError("--video needs --maps: a map (.h5) or a folder of maps")
