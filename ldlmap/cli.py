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


@app.command()
def lines(
    input_path: Path = typer.Argument(..., metavar="INPUT", help="Point cloud (.ply/.pcd/.txt) or mesh (.obj/.ply)."),
    output: Path = typer.Option(..., "-o", "--output", help="Output .obj; a .txt with the same stem is written too."),
    lam: float = typer.Option(0.1, "--lambda", help="Length filter: drop lines shorter than lambda (bx+by+bz)/3."),
    no_filter: bool = typer.Option(False, "--no-filter", help="Write all extracted lines (no length filter)."),
    png: Optional[Path] = typer.Option(None, "--png", help="Also write a top-view picture of the lines."),
) -> None:
    """Extract 3D line segments from a point cloud and write them as .obj and .txt."""
    from ldlmap.errors import LdlError
    from ldlmap.io.pointcloud import read_point_cloud
    from ldlmap.lines3d import draw_top_view, extract_lines_with_stats, filter_by_length, write_line_files
    from ldlmap.principal3d import principal_directions_3d

    pc = read_point_cloud(input_path)
    raw, stats = extract_lines_with_stats(pc.points)
    lo, hi = pc.bounds()
    kept, mask, thr = filter_by_length(raw, lo, hi, lam=lam)
    out_lines = raw if no_filter else kept
    if len(out_lines) == 0:
        raise LdlError(f"no 3D lines found in {input_path}")
    paths = write_line_files(output, out_lines)
    console.print(f"{len(pc)} points -> {stats['planes']} planes -> {len(raw)} lines; length threshold "
                  f"{thr:.3f} m keeps {len(kept)} (kept ratio {mask.mean():.3f})"
                  + (" [filter off: all lines written]" if no_filter else ""), soft_wrap=True)
    console.print("wrote " + ", ".join(str(p) for p in paths), soft_wrap=True)
    if png is not None:
        principal = principal_directions_3d(out_lines) if len(out_lines) else None
        draw_top_view(out_lines, png, principal=principal, dropped=None if no_filter else raw[~mask])
        console.print(f"wrote {png}", soft_wrap=True)


@app.command()
def synth(
    out: Path = typer.Argument(..., help="Output dataset folder (OmniScenes layout)."),
    preset: Optional[str] = typer.Option(None, "--preset", help="Random-room preset (demo, standard); default demo."),
    spec: Optional[list[Path]] = typer.Option(None, "--spec", help="Scene spec .toml (repeatable); replaces --preset."),
    seed: int = typer.Option(0, "--seed", help="Random seed: same seed, identical files."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a non-empty OUT folder."),
    no_illumination: bool = typer.Option(False, "--no-illumination", help="Skip the extreme_* illumination splits."),
    width: Optional[int] = typer.Option(None, "--width", help="Panorama width (height = width / 2); default from the spec."),
    per_split: Optional[int] = typer.Option(None, "--per-split", help="Panoramas per split (default from the spec)."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Generate a synthetic panoramic dataset: scans, meshes, 3D edges, panoramas with poses."""
    from rich.table import Table

    from ldlmap.errors import InputError
    from ldlmap.synth.generate import generate_dataset

    if spec and preset:
        raise InputError("use either --preset or --spec, not both")
    s = generate_dataset(out, preset=preset, spec_paths=spec or [], seed=seed, overwrite=overwrite,
                         progress=not quiet, illumination=not no_illumination, width=width, per_split=per_split)
    table = Table(title=f"synthetic dataset {s.out} (seed {s.seed}, {s.width}x{s.height})")
    table.add_column("split")
    table.add_column("panoramas", justify="right")
    for split, n in s.splits.items():
        table.add_row(split, str(n))
    table.add_row("[bold]total[/]", f"[bold]{s.images}[/]")
    console.print(table)
    console.print("scenes: " + ", ".join(f"{name} ({s.points[name]:,} scan points)" for name in s.scenes), soft_wrap=True)
    console.print(f"done in {s.seconds:.1f} s", soft_wrap=True)
