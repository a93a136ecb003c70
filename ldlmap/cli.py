"""``ldlmap``: the offline side of the LDL toolkit (maps, lines, synthetic data).

The commands only parse arguments and call library functions; heavy imports happen inside the
commands so that ``ldlmap --help`` answers instantly.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ldlmap.cli_common import console, make_app

app = make_app("ldlmap", "Build LDL maps (3D lines, principal directions, features) and synthetic datasets.")


def run() -> None:  # console-script entry point
    app()


# Commands are added below, one function each. Keep each one short: parse, call, print.
