"""The checks of ``ldlloc run``'s walk options (one-line errors, before anything is read)."""

from __future__ import annotations

from ldlmap.core.errors import InputError
from ldlloc.walk.order import ORDERS


def check_walk_options(walk: bool, order: str | None, images: str | None, ray: str | None, save_vis) -> None:
    """``--order`` goes with ``--walk --images`` and is one of :data:`ORDERS`; a walk runs in this
    process (not on Ray: one walk is never split) and writes no pictures."""
    if order is not None and not walk:
        raise InputError("--order goes with --walk")
    if order is not None and order not in ORDERS:
        raise InputError(f"--order must be {' or '.join(ORDERS)}, got {order!r}")
    if order is not None and images is None:
        raise InputError("--order goes with --images (a dataset knows its walks' order)")
    if walk and ray is not None:
        raise InputError("--walk runs in this process: drop --ray (a walk is localized as a whole, never split)")
    if walk and save_vis is not None:
        raise InputError("--walk writes no pictures: drop --save-vis")


def check_video_options(video, fps: float | None, every: int | None, images, root, dataset, ray, save_vis,
                        resume: bool, maps) -> None:
    """``--fps`` and ``--every`` go with ``--video``; a video run takes no dataset or images, runs in
    this process, writes no pictures, is not resumed (a rerun localizes it again) and needs ``--maps``."""
    if video is None:
        raise InputError(f"{'--fps' if fps is not None else '--every'} goes with --video")
    given = [o for o, v in (("--images", images), ("--root", root), ("--dataset", dataset), ("--ray", ray),
                            ("--save-vis", save_vis), ("--resume", resume)) if v]
    if given:
        raise InputError(f"--video runs alone: drop {', '.join(given)}")
    if maps is None:
        raise InputError("--video needs --maps: a map (.h5) or a folder of maps")
