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
