"""The localization options of ``ldlloc localize`` and ``ldlloc run``, checked (one line each,
before any work) and turned into :class:`~ldlloc.pipeline.LocalizeParams`."""

from __future__ import annotations

from pathlib import Path

from ldlloc.batch.which_map import TOP_MAPS
from ldlloc.pipeline import LocalizeParams, check_localize_params
from ldlloc.search.pose_search import SearchParams
from ldlmap.core.cli_common import check_range
from ldlmap.core.errors import InputError

MAX_TOP_MAPS = 1000  # --top-maps: each of them is refined
OPTION_NAMES = {"loss": "loss", "top_k": "--top-k", "refine_mode": "--refine", "query_frame": "--query-frame",
                "max_tilt_deg": "--max-tilt"}  # the options of LocalizeParams' checked fields


def localize_params(top_k: int, loss: str, no_decompose: bool, no_refine: bool, privacy: bool,
                    features: str | None, weights: Path | None, max_tilt: float | None = None,
                    refine: str = "auto", query_frame: str = "map") -> LocalizeParams:
    """The parameters the options give, checked by the library (:func:`~ldlloc.pipeline.check_localize_params`,
    one-line errors naming the option) before any work; here only what the options alone can get
    wrong: ``--no-refine`` with another ``--refine``."""
    params = LocalizeParams(search=SearchParams(top_k=top_k, loss=loss, decompose=not no_decompose),
                            features=features, weights=str(weights) if weights else None,
                            do_refine=not no_refine, privacy=privacy, max_tilt_deg=max_tilt, refine_mode=refine,
                            query_frame=query_frame)
    check_localize_params(params, OPTION_NAMES)
    if no_refine and refine not in ("auto", "none"):  # auto: the default, i.e. --refine not given
        raise InputError(f"--no-refine (= --refine none) contradicts --refine {refine}: give one of them")
    return params


def top_maps_or_default(top_maps: int | None) -> int:
    """``--top-maps`` (default :data:`TOP_MAPS`), checked."""
    top_maps = TOP_MAPS if top_maps is None else top_maps
    check_range(top_maps, "--top-maps", 1, MAX_TOP_MAPS, integer=True)
    return top_maps


def path_option(value: str | None, option: str) -> Path | None:
    """A path option as a Path; an empty one is refused (it would mean the working folder)."""
    if value is not None and not value.strip():
        raise InputError(f"{option} is empty: give a path")
    return None if value is None else Path(value)
