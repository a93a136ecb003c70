"""``ldlloc``: the online side of the LDL toolkit (localize panoramas against LDL maps)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ldlmap.cli_common import console, make_app

app = make_app("ldlloc", "Localize panoramas against LDL maps with line distance functions.")


def run() -> None:  # console-script entry point
    app()


# Commands are added below, one function each. Keep each one short: parse, call, print.
