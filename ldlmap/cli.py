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


@app.command()
def info(map_path: Path = typer.Argument(..., help="An LDL map (.h5) written by `ldlmap build`.")) -> None:
    """Print a summary of an LDL map: lines, principal directions, translations, features."""
    from rich.table import Table

    from ldlmap.mapfile import read_map_header

    h = read_map_header(map_path)
    table = Table(title=f"LDL map {map_path}", show_header=False)
    table.add_column("field", style="bold")
    table.add_column("value")
    rows = [
        ("scene", h["name"]),
        ("format version", str(h["format_version"])),
        ("3D lines (raw -> kept)", f"{h['num_lines_raw']} -> {h['num_lines']} (kept ratio {h['kept_ratio']:.3f}, "
                                   f"length threshold {h['length_threshold']:.3f} m)"),
        ("candidate translations", str(h["num_translations"])),
        ("cloud points stored", str(h["num_cloud_points"])),
        ("features", "none (lines-only map)" if h["feature_backend"] is None else
         f"{h['feature_backend']}: {h['num_keypoints']} keypoints in {h['num_views']} views"),
        ("precomputed fields", ", ".join(h["fields"]) or "none"),
        ("file size", f"{h['file_size_bytes'] / 1e6:.2f} MB"),
        ("built with", ", ".join(f"{k} {v}" for k, v in h["library_versions"].items())),
    ]
    for k, v in rows:
        table.add_row(k, v)
    console.print(table)
