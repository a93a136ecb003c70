"""``ldlmap``: the offline side of the LDL toolkit (maps, lines, synthetic data).

The commands only parse arguments and call library functions. numpy and the modules that carry
out a command are named here through :func:`~ldlmap.core.lazy.lazy_module`: they load when a
command runs, so that ``ldlmap --help`` answers instantly.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from ldlmap.core.cli_common import (DATASET_HELP, StageProgress, check_device, check_range, check_threads, console,
                                    dataset_label, err_console, make_app, open_dataset_root, ray_option,
                                    refuse_map_level, set_threads, threads_option)
from ldlmap.core.errors import (InputError, LdlError, check_writable_output, refuse_overwriting_inputs,
                                refuse_replacing_other_files)
from ldlmap.core.lazy import lazy_module

np = lazy_module("numpy")
batch_prepare = lazy_module("ldlmap.batch.prepare")
core_frame = lazy_module("ldlmap.core.frame")
core_pictures = lazy_module("ldlmap.core.pictures")
datasets = lazy_module("ldlmap.datasets")
ifc_maps = lazy_module("ldlmap.map.ifc_maps")
io_cloud = lazy_module("ldlmap.io.cloud")
io_e57 = lazy_module("ldlmap.io.e57")
io_ifc = lazy_module("ldlmap.io.ifc")
io_linefiles = lazy_module("ldlmap.io.linefiles")
io_pointcloud = lazy_module("ldlmap.io.pointcloud")
lines3d = lazy_module("ldlmap.lines3d")
lines_principal = lazy_module("ldlmap.lines3d.principal")
map_build = lazy_module("ldlmap.map.build")
map_params = lazy_module("ldlmap.map.params")
map_inputs = lazy_module("ldlmap.map.inputs")
map_pictures = lazy_module("ldlmap.map.pictures")
mapfile = lazy_module("ldlmap.map.mapfile")
omniscenes = lazy_module("ldlmap.datasets.omniscenes")
ray_cluster = lazy_module("ldlmap.batch.ray_cluster")
ray_prepare = lazy_module("ldlmap.batch.ray_prepare")
scanner_images = lazy_module("ldlmap.datasets.scanner_images")
synth_capture = lazy_module("ldlmap.synth.capture")
synth_generate = lazy_module("ldlmap.synth.generate")
synth_walk = lazy_module("ldlmap.synth.walk")

app = make_app("ldlmap", "Build LDL maps (3D lines, principal directions, features) and synthetic datasets.")


# Commands are added below, one function each. Keep each one short: parse, call, print.

# Options shared by `build` and `prepare` (maps without a scan: line files, ZInD layouts).
TRANS_SPACING = typer.Option(None, "--trans-spacing", help="Maps without a scan (line files, ZInD layouts): "
                             "candidate translations this many metres apart (default 0.3).")
CAMERA_HEIGHT = typer.Option(None, "--camera-height", metavar="MIN:MAX", help="Camera-height band in metres "
                             "above each floor where the candidate translations go (e.g. 0.9:1.7; floors are found where "
                             "the vertical lines begin); default: ZInD's camera height, else 0.3:2.2.")
UP = typer.Option(None, "--up", help="The input's up axis: x, y, z, -x, -y, -z, or auto (default: the COLMAP cameras' "
                  "down axes, else the lines' vertical structure); the map is rotated into z-up once.")
EXTRACTION = typer.Option(None, "--feature-extraction", help="Where features of the panoramas are extracted: equirect "
                          "(the whole image) | cube (its six 90-degree faces); default: cube for aliked, equirect for "
                          "the others (measured); the queries follow the map.")
SCALE = typer.Option(None, "--scale", help="Multiply the input coordinates by this (metres per input unit: 0.001 "
                     "for millimetres, the scale of an SfM frame); default 1.")


@app.command()
def info(map_path: Path = typer.Argument(..., metavar="MAP", help="An LDL map (.h5) written by `ldlmap build`."),
         png: Optional[Path] = typer.Option(None, "--png", help="Also write a picture of the map (top view + "
                                            "panorama with lines, legend; .png, .jpg, .jpeg, .bmp, .tif, .tiff, "
                                            ".webp).")
         ) -> None:
    """Print a summary of an LDL map: lines, principal directions, translations, features.

    The whole map is read and validated first (layout, values, checksums): a damaged map fails
    with one line."""


    if png is not None:
        core_pictures.check_picture_path(png, "--png")
        refuse_overwriting_inputs([map_path], [png])
        check_writable_output(png, "--png")
    m = mapfile.read_map(map_path)
    h = mapfile.read_map_header(map_path)
    table = Table(title=f"LDL map {map_path}", show_header=False)
    table.add_column("field", style="bold")
    table.add_column("value")
    rows = [
        ("scene", _scene_name(h["name"], map_path)),
        ("format version", str(h["format_version"])),
        ("3D lines (raw -> kept)", f"{h['num_lines_raw']} -> {h['num_lines']} (kept ratio {h['kept_ratio']:.3f}, "
                                   f"length threshold {h['length_threshold']:.3f} m)"),
        *_principal_rows(h),
        ("candidate translations", _translations_summary(h)),
        ("cloud points stored", str(h["num_cloud_points"])),
        ("features", "none (lines-only map)" if h["feature_backend"] is None else
         f"{h['feature_backend']}: {h['num_keypoints']} keypoints in {h['num_views']} views"
         + (" (cube faces)" if h.get("feature_extraction") == "cube" else "")),
        ("precomputed fields", ", ".join(h["fields"]) or "none"),
        ("line visibility", "per translation (walls hide lines)" if h.get("line_visibility") else "every line seen"),
        ("file size", f"{h['file_size_bytes'] / 1e6:.2f} MB"),
        ("checksums", "verified" if h["checksummed"] else "none (written before checksums)"),
        ("built with", ", ".join(f"{k} {v}" for k, v in h["library_versions"].items())),
    ]
    for k, v in rows:
        table.add_row(k, v)
    console.print(table)
    if png is not None:

        map_pictures.map_picture(m, png, name=map_path.name)
        console.print(f"wrote {png}", soft_wrap=True)


def _scene_name(stored: str, map_path: Path) -> str:
    """The map's scene as `ldlloc run` names it: the stored name, which `build` and `prepare` make
    the file's stem (its path below the maps folder); a file renamed since (or a map built before
    that rule) shows its stem, which `run` uses, with the stored name beside it."""
    if Path(stored).name == map_path.stem:
        return stored
    return f"{map_path.stem} (stored as {stored!r}; `ldlloc run --maps` names it by the file)"


def _principal_rows(header: dict) -> list[tuple[str, str]]:
    """Table rows: the K principal directions (unit vectors, world frame) with their line counts,
    the angles between them (of the first 3: more are horizontals), and the lines in no group."""
    P, counts = np.asarray(header["principal_directions"], dtype=np.float64), header["line_group_counts"]
    vecs = "\n".join(f"d{i} = [{P[i, 0]: .4f}, {P[i, 1]: .4f}, {P[i, 2]: .4f}]"
                     + (f"  {counts[i]} lines" if counts else "") for i in range(len(P)))
    ang = {f"d{i}-d{j}": np.degrees(np.arccos(np.clip(P[i] @ P[j], -1.0, 1.0))) for i, j in ((0, 1), (0, 2), (1, 2))}
    rows = [("principal directions", vecs),
            ("angles between them", ", ".join(f"{k} {v:.2f} deg" for k, v in ang.items()))]
    if counts:
        rows.append(("lines in no group", str(counts[-1])))
    return rows


def _translations_summary(header: dict) -> str:
    """Count and how the candidates were chosen (spacing and height band for maps without a scan)."""
    n, cfg = header["num_translations"], header["build_config"]
    how = cfg.get("translations") or {}
    if how.get("method") == "spacing":
        band, floors = how.get("camera_height"), how.get("floors")
        above = " above the floor" if floors is not None and how.get("camera_height_source") != "layout" else ""
        z = f", camera height {band[0]:.2f}-{band[1]:.2f} m{above}" if band else ""
        return f"{n}, spaced {how['spacing']:.2f} m over the {how.get('region', 'free space')}{z}"
    method = how.get("method") or cfg.get("translation_method")
    band = how.get("camera_height", how.get("camera_height_above_floor"))  # the latter: maps before floors were found
    z = f", {band[0]:.2f}-{band[1]:.2f} m above the floor" if band else ""
    return f"{n}" + (f" ({method}, N_t = {cfg.get('num_translations')}{z})" if method else "")


def parse_band(text: Optional[str], option: str) -> Optional[tuple[float, float]]:
    """``"MIN:MAX"`` as a (min, max) pair (None stays None); its bounds are checked by the build's parameters
    (``CandidateParams.check``), whether the band meets the scene by the build (``scene_translations``)."""
    if text is None:
        return None
    try:
        lo, hi = (float(x) for x in text.split(":"))
    except ValueError:
        raise InputError(f"{option} must be MIN:MAX in metres (e.g. 1.2:1.7), got {text!r}") from None
    return lo, hi


@app.command()
def lines(
    input_path: Path = typer.Argument(..., metavar="INPUT", help="Point cloud (.ply/.pcd/.txt/.las/.laz), scan (.e57) "
                                      "or mesh (.obj/.ply/.glb/.gltf)."),
    output: Path = typer.Option(..., "-o", "--output", help="Output .obj; a .txt with the same stem is written too."),
    lam: float = typer.Option(0.1, "--lambda", help="Length filter: drop lines shorter than lambda (bx+by+bz)/3."),
    no_filter: bool = typer.Option(False, "--no-filter", help="Write all extracted lines (no length filter)."),
    png: Optional[Path] = typer.Option(None, "--png", help="Also write a top-view picture of the lines "
                                       "(.png, .jpg, .jpeg, .bmp, .tif, .tiff, .webp)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace existing output files that are not line "
                                   "files (line files written before are replaced without it)."),
) -> None:
    """Extract 3D line segments from a point cloud and write them as .obj and .txt."""
    map_params.LengthFilterParams(lam=lam).check()
    if png is not None:
        core_pictures.check_picture_path(png, "--png")
    if output.is_dir():
        raise LdlError(f"output {output} is a folder; give a file name (e.g. {output / 'lines.obj'})")
    line_outputs = [output.with_suffix(".obj"), output.with_suffix(".txt")]
    refuse_overwriting_inputs([input_path], [*line_outputs, png])
    for path in line_outputs:
        refuse_replacing_other_files(path, lambda p: io_linefiles.sniff_line_file(p) is not None, "a 3D line file", overwrite)
    for path, option in ((line_outputs[0], "-o"), (png, "--png")):
        if path is not None:
            check_writable_output(path, option)
    _refuse_line_file(input_path)
    if input_path.suffix.lower() in map_inputs.SCANNER_SUFFIXES:  # E57, LAS/LAZ, glTF (docs/inputs.md)
        pc, note = map_inputs.read_scanner_file(input_path, io_cloud.DEFAULT_MESH_SAMPLES)
        console.print(note, soft_wrap=True, highlight=False)
    else:
        pc = io_pointcloud.read_point_cloud(input_path)
    _check_scan_extent(pc.points)
    raw, stats = lines3d.extract_lines_with_stats(pc.points)
    lo, hi = pc.bounds()
    kept, mask, thr = lines3d.filter_by_length(raw, lo, hi, lam=lam)
    out_lines = raw if no_filter else kept
    if len(out_lines) == 0:
        raise LdlError(f"no 3D lines found in {input_path}")
    paths = lines3d.write_line_files(output, out_lines)
    console.print(f"{len(pc)} points -> {stats['planes']} planes -> {len(raw)} lines; length threshold "
                  f"{thr:.3f} m keeps {len(kept)} (kept ratio {mask.mean():.3f})"
                  + (" [filter off: all lines written]" if no_filter else ""), soft_wrap=True)
    console.print("wrote " + ", ".join(str(p) for p in paths), soft_wrap=True)
    if png is not None:
        principal = lines_principal.principal_directions_3d(out_lines) if len(out_lines) else None
        lines3d.draw_top_view(out_lines, png, principal=principal, dropped=None if no_filter else raw[~mask])
        console.print(f"wrote {png}", soft_wrap=True)


def _check_scan_extent(points) -> None:
    """Before extracting lines: refuse, as `build` does, a scan whose extent is not in metres
    (millimetres, or an extent whose grids would not fit in memory)."""


    try:
        core_frame.check_extent(np.subtract(*lines3d.robust_bounds(points)[::-1]))
    except InputError as exc:  # `lines` has no --scale: convert the scan, or let `build` scale it
        raise InputError(str(exc).split(" A map must")[0] + " Lines are extracted in metres: convert the scan, or "
                         "build the map with `ldlmap build SCAN --scale 0.001`") from None


def _refuse_line_file(path: Path) -> None:
    """One line saying what to do when `ldlmap lines` is given a 3D line file instead of a scan."""
    kind = io_linefiles.sniff_line_file(path) if path.is_file() else None
    if kind is not None:
        raise InputError(f"{path} is a 3D line file ({io_linefiles.LINE_FORMAT_NAMES[kind]}), not a scan: it has its lines "
                         f"already; build a map with `ldlmap build {path}` (lines-only) or "
                         f"`ldlmap build SCAN --lines {path}`")


@app.command()
def synth(
    out: Path = typer.Argument(..., help="Output dataset folder (OmniScenes layout)."),
    preset: Optional[str] = typer.Option(None, "--preset", help="Random-room preset (demo, standard; multiroom: 4 demo rooms "
                                          "in one scan, one scene multiroom_1; building: 3 floors of 12 rooms, "
                                          "corridors and a stairwell, one scene per floor; building_small: 2 floors "
                                          "of 3 rooms; rooms that are not boxes: angled, sloped, stepped, arched, "
                                          "curved, shapes = one of each; furnished: kitchens, bathrooms, bedrooms "
                                          "and living rooms as densely furnished as homes, each with its layout "
                                          "line file); default demo."),
    spec: Optional[list[Path]] = typer.Option(None, "--spec", help="Scene spec .toml (repeatable); replaces --preset."),
    seed: int = typer.Option(0, "--seed", help="Random seed in [0, 2**32): same seed, identical files."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a non-empty OUT folder."),
    no_illumination: bool = typer.Option(False, "--no-illumination", help="Skip the extreme_* illumination splits."),
    width: Optional[int] = typer.Option(None, "--width", help="Panorama width (height = width / 2); default from the spec."),
    per_split: Optional[int] = typer.Option(None, "--per-split", help="Panoramas per split (default from the spec)."),
    walk: Optional[str] = typer.Option(None, "--walk", help="Also capture a walk through the scene(s), as the split "
                                       "walk_tour (tour: a photo every 1-3 m), walk_video (video: a frame every "
                                       "0.1-0.3 m, motion blur, also video/walk_video.mp4) or both (tour,video); "
                                       "through doors, down corridors and up the stairwell (docs/synthetic.md#walks)."),
    walk_step: Optional[float] = typer.Option(None, "--walk-step", help="--walk: mean step in metres (steps are "
                                              "0.5-1.5 x it; default 2 for tour, 0.2 for video)."),
    doors: Optional[str] = typer.Option(None, "--doors", help="A building's doors in its scans and panoramas: closed "
                                        "(default: a panel in each doorway) or open (the next room is seen "
                                        "through the doorway)."),
    walk_doors: Optional[str] = typer.Option(None, "--walk-doors", help="--walk in a building: its doors closed or "
                                             "open in the walk's frames (default: as --doors; a tour with the doors "
                                             "open through a building scanned with them closed, or the reverse)."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Generate a synthetic panoramic dataset: scans, meshes, 3D edges, panoramas with poses."""


    if spec and preset:
        raise InputError("use either --preset or --spec, not both")
    synth_capture.check_dataset_seed(seed)
    check_range(width, "--width", synth_capture.MIN_WIDTH, synth_capture.MAX_WIDTH, integer=True,
                why="rendering holds about 450 bytes per pixel")
    check_range(per_split, "--per-split", 0, synth_capture.MAX_PER_SPLIT, integer=True)
    walks = synth_walk.parse_walk(walk)
    synth_walk.check_walk_step(walk_step, walks)
    building = not spec and synth_generate.is_building_preset(preset)
    scanned = synth_walk.check_doors(doors, building)
    walked = synth_walk.check_walk_doors(walk_doors, walks, building, default=scanned)
    refuse_overwriting_inputs(spec or [], [out])
    synth_capture.refuse_replacing_other_dataset(out, overwrite)
    kept = synth_capture.files_not_generated(out) if overwrite and omniscenes.written_by_synth(out) else []
    s = synth_generate.generate_dataset(out, preset=preset, spec_paths=spec or [], seed=seed, overwrite=overwrite,
                         progress=not quiet, illumination=not no_illumination, width=width, per_split=per_split,
                         walk=walks, walk_step=walk_step, doors=scanned, walk_doors=walked)
    table = Table(title=f"synthetic dataset {s.out} (seed {s.seed}, {s.width}x{s.height})")
    table.add_column("split")
    table.add_column("panoramas", justify="right")
    for split, n in s.splits.items():
        table.add_row(split, str(n))
    table.add_row("[bold]total[/]", f"[bold]{s.images}[/]")
    console.print(table)
    console.print("scenes: " + ", ".join(f"{name} ({s.points[name]:,} scan points)" for name in s.scenes), soft_wrap=True)
    if kept:
        tops = sorted({k.split("/")[0] + ("/" if "/" in k else "") for k in kept})
        console.print(f"kept {len(kept)} file(s) that `ldlmap synth` did not write: {', '.join(tops[:6])}"
                      + (", ..." if len(tops) > 6 else ""), soft_wrap=True)
    console.print(f"done in {s.seconds:.1f} s", soft_wrap=True)


@app.command()
def build(
    input_path: Path = typer.Argument(..., metavar="INPUT", help="Colored point cloud (.ply/.pcd/.txt/.las/.laz), "
                                      "scan (.e57), mesh (.obj/.ply/.glb/.gltf), IFC model (.ifc: lines-only, one map "
                                      "per storey), COLMAP model folder, or a 3D line file alone (lines-only map); "
                                      "docs/inputs.md."),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="Map file (default: INPUT with .h5); an IFC "
                                          "model of several storeys: a folder (default: INPUT_storeys/)."),
    stations: Optional[str] = typer.Option(None, "--stations", help="E57: only these scan stations, by name or "
                                           "0-based index, comma-separated (default: all)."),
    storey: Optional[str] = typer.Option(None, "--storey", help="IFC: only this storey's map (default: one map per "
                                         "storey)."),
    include: Optional[str] = typer.Option(None, "--include", help="IFC: more element classes for the lines, "
                                          "comma-separated (e.g. IfcFurnishingElement,IfcFlowTerminal; walls, slabs, "
                                          "coverings, columns, doors and windows always)."),
    lines_file: Optional[Path] = typer.Option(None, "--lines", help="3D line file to use instead of extracting lines "
                                              "(Line3D++ .txt/.obj, 3DLineDetection .txt, ours)."),
    images: Optional[Path] = typer.Option(None, "--images", help="COLMAP model without fused.ply: its photos, to "
                                          "reconstruct 3D lines from (default: the workspace's images folder)."),
    features: str = typer.Option("sift", "--features", help="Local features for refinement: sift (no weights) | aliked | disk | xfeat (packaged weights, "
                                  "LightGlue matching) | superpoint (your weights) | none."),
    weights: Optional[Path] = typer.Option(None, "--weights", help="SuperPoint checkpoint (else $LDL_SUPERPOINT_WEIGHTS, cache, download)."),
    extraction: Optional[str] = EXTRACTION,
    num_trans: Optional[int] = typer.Option(None, "--num-trans", help="N_t candidate translations (default 800)."),
    method: Optional[str] = typer.Option(None, "--translations", help="octree (OmniScenes) | grid (Stanford)."),
    num_views: Optional[int] = typer.Option(None, "--num-views", help="Views rendered for features (default 40)."),
    lam: Optional[float] = typer.Option(None, "--lambda", help="Length filter ratio lambda (default 0.1)."),
    min_length: Optional[float] = typer.Option(None, "--min-line-length", help="Absolute length threshold in metres "
                                               "instead of lambda's (maps of several rooms: about one room's 0.1 x "
                                               "mean extent, e.g. 0.45)."),
    trans_spacing: Optional[float] = TRANS_SPACING,
    camera_height: Optional[str] = CAMERA_HEIGHT,
    up: Optional[str] = UP,
    scale: Optional[float] = SCALE,
    device: str = typer.Option("cpu", "--device", help="Torch device for rendering and SuperPoint: cpu | cuda."),
    png: Optional[Path] = typer.Option(None, "--png", help="Also write a picture of the map (top view + panorama "
                                       "with lines, legend; .png, .jpg, .jpeg, .bmp, .tif, .tiff, .webp)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing output that is not an LDL "
                                   "map (a map built before is replaced without it; another HDF5 file is not)."),
    threads: int = threads_option(),
) -> None:
    """Build an LDL map (3D lines, principal directions, translations, features) from a scan."""


    check_threads(threads)
    check_device(device)
    params = map_params.params_with(map_params.BuildParams(), features=features, weights=str(weights) if weights else None,
                                    feature_extraction=extraction, num_translations=num_trans,
                                    translation_method=method, num_views=num_views, lam=lam, min_line_length=min_length,
                                    device=device, trans_spacing=trans_spacing,
                                    camera_height=parse_band(camera_height, "--camera-height"), up=up, scale=scale)
    params.check()
    if png is not None:
        core_pictures.check_picture_path(png, "--png")
    station_list = _check_input_options(input_path, stations, storey, include, lines_file, images)
    if input_path.suffix.lower() == ".ifc":
        return _build_ifc(input_path, output, storey, include, png, overwrite, threads,
                          map_params.params_with(map_params.BuildParams(), num_views=num_views, lam=lam,
                                                 min_line_length=min_length, device=device, trans_spacing=trans_spacing,
                                                 up=up, scale=scale, camera_height=params.translations.camera_height))
    output = output if output is not None else input_path.with_suffix(".h5")
    refuse_overwriting_inputs([input_path, lines_file, images, weights], [output, png])
    batch_prepare.refuse_replacing_non_map(output, overwrite)
    for path, option in ((output, "-o"), (png, "--png")):
        if path is not None:
            check_writable_output(path, option)

    params = map_params.params_with(params, stations=station_list)
    set_threads(threads)
    with StageProgress(console, f"map of {input_path.name}") as bar:
        report = map_build.build_map(input_path, output, lines_file, params, images_path=images,
                           progress=lambda stage, done, total: bar.stage(input_path.name, stage, done, total))
    if report.counts.get("note"):
        console.print(report.counts["note"], soft_wrap=True)
    table = Table(title=f"map {report.path}")
    table.add_column("stage")
    table.add_column("seconds", justify="right")
    for k, v in report.seconds.items():
        table.add_row(k, f"{v:.2f}")
    console.print(table)
    c = report.counts
    console.print(f"{c['lines_raw']} lines -> {c['lines']} kept (ratio {c['kept_ratio']:.3f}), "
                  f"{c['translations']} translations, {c['keypoints']} keypoints in {c['views']} views "
                  f"({params.features.backend if c['views'] else 'no features'}), {c['size_mb']:.1f} MB", soft_wrap=True)
    _print_notes(report)
    if png is not None:

        map_pictures.map_picture(mapfile.read_map(report.path), png, name=Path(report.path).name)
        console.print(f"wrote {png}", soft_wrap=True)


def _check_input_options(input_path: Path, stations: Optional[str], storey: Optional[str], include: Optional[str],
                         lines_file: Optional[Path], images: Optional[Path]) -> Optional[tuple[str, ...]]:
    """The options that go with one kind of input only, before any work; the E57 stations as a tuple."""
    suffix = input_path.suffix.lower()
    if stations is not None and suffix != ".e57":
        raise InputError(f"--stations goes with an E57 scan, not {input_path.name}")
    for option, value in (("--storey", storey), ("--include", include)):
        if value is not None and suffix != ".ifc":
            raise InputError(f"{option} goes with an IFC model, not {input_path.name}")
    if suffix == ".ifc" and (lines_file is not None or images is not None):
        raise InputError("an IFC model's lines come from its elements: --lines and --images do not apply")
    if stations is None:
        return None
    names = tuple(x.strip() for x in stations.split(","))
    if not all(names):
        raise InputError(f"--stations must be station names or indices separated by commas, got {stations!r}")
    return names


def _build_ifc(model: Path, output: Optional[Path], storey: Optional[str], include: Optional[str], png: Optional[Path],
               overwrite: bool, threads: int, params) -> None:
    """`build MODEL.ifc`: one lines-only map per storey (ldlmap/map/ifc_maps.py), or the --storey's."""
    classes = tuple(c.strip() for c in include.split(",")) if include is not None else ()
    if include is not None and not all(classes):
        raise InputError(f"--include must be IFC class names separated by commas, got {include!r}")
    names = io_ifc.storey_names(io_ifc.open_ifc(model))
    if not names:
        raise InputError(f"IFC model has no storeys (IfcBuildingStorey): {model}; maps are built per storey")
    if storey is not None:
        if storey not in names:
            raise InputError(f"--storey {storey!r}: no such storey in {model} (storeys: {', '.join(names)})")
        names = [storey]
    if png is not None and len(names) > 1:
        raise InputError("--png draws one map: pick a storey with --storey NAME")
    outputs = ifc_maps.storey_outputs(model, names, output)
    refuse_overwriting_inputs([model], [*outputs.values(), png])
    for path in outputs.values():
        batch_prepare.refuse_replacing_non_map(path, overwrite)
        check_writable_output(path, "-o")
    set_threads(threads)
    with StageProgress(console, f"maps of {model.name}", total=len(names), unit="storeys") as bar:
        reports, note = ifc_maps.build_ifc_maps(model, outputs, params, classes,
                                       progress=lambda name, stage, done, total: bar.stage(name, stage, done, total))
    console.print(note, soft_wrap=True, highlight=False)
    for r in reports:
        c = r.counts
        console.print(f"{r.path}: {c['lines_raw']} lines -> {c['lines']} kept, {c['translations']} translations, "
                      f"lines-only ({r.seconds['total']:.1f} s)", soft_wrap=True, highlight=False)
        _print_notes(r)
    if png is not None:

        map_pictures.map_picture(mapfile.read_map(reports[0].path), png, name=Path(reports[0].path).name)
        console.print(f"wrote {png}", soft_wrap=True)


@app.command()
def e57(
    scan: Path = typer.Argument(..., metavar="SCAN", help="An E57 scan (.e57)."),
    images: Optional[Path] = typer.Option(None, "--images", metavar="OUT", help="Write the stations' spherical "
                                          "images with their poses into this folder as a dataset (OmniScenes "
                                          "layout, split `scanner`) that `ldlloc run --root OUT` checks the map on."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace the scanner images written into OUT before."),
) -> None:
    """List an E57 scan's stations and images; with --images, write its panoramas as a dataset.

    Pinhole and cylindrical images (and spherical ones that do not cover the whole sphere) are
    listed and skipped: the maps are localized with panoramas."""


    names = io_e57.station_names(scan)
    listed = io_e57.e57_images(scan)
    done = None
    if images is not None:  # written (or refused in one line) before anything is printed

        refuse_overwriting_inputs([scan], [images])
        done = scanner_images.write_e57_dataset(scan, images, overwrite)
    console.print(f"{scan}: {len(names)} station(s): " + ", ".join(f"{i}:{n}" for i, n in enumerate(names)),
                  soft_wrap=True, highlight=False)
    for im in listed:
        where = "" if im.center is None else " at (" + ", ".join(f"{x:.2f}" for x in np.asarray(im.center)) + ")"
        console.print(f"  image {im.name}: {im.kind} {im.width}x{im.height}{where}" + (f" - {im.note}" if im.note else ""),
                      soft_wrap=True, highlight=False)
    if done is not None:
        console.print(f"wrote {len(done.written)} panorama(s) with poses into {done.root} (split scanner, scene "
                      f"{done.scene}); {len(done.skipped)} image(s) skipped", soft_wrap=True, highlight=False)
        console.print(f"check a map on them: ldlmap build {scan} -o {done.root / 'maps' / (done.scene + '.h5')} && "
                      f"ldlloc run --root {done.root} --split scanner", soft_wrap=True, highlight=False)


def _print_notes(report) -> None:
    """The build's notes on stdout and its warnings as ``warning:`` lines on stderr."""
    for line in report.notes:
        console.print(line, soft_wrap=True, highlight=False)
    for line in report.warnings:
        err_console.print(f"[bold yellow]warning:[/] {line}", soft_wrap=True, highlight=False)


@app.command()
def prepare(
    root: Optional[Path] = typer.Argument(None, help="Dataset root (default ./data/<dataset>)."),
    dataset: Optional[str] = typer.Option(None, "--dataset", help=DATASET_HELP),
    maps: Optional[Path] = typer.Option(None, "--maps", help="Folder for the maps (default ROOT/maps)."),
    map_level: Optional[str] = typer.Option(None, "--map-level", help="ZInD: one map per complete room (room, the "
                                            "default) or per floor (floor, every room in one map)."),
    features: Optional[str] = typer.Option(None, "--features", help="sift | aliked | disk | xfeat | superpoint | none (default sift; "
                                           "ZInD layout maps: none)."),
    weights: Optional[Path] = typer.Option(None, "--weights", help="SuperPoint checkpoint."),
    extraction: Optional[str] = EXTRACTION,
    num_trans: Optional[int] = typer.Option(None, "--num-trans", help="N_t (default: 800 OmniScenes, 1700 Stanford)."),
    num_views: Optional[int] = typer.Option(None, "--num-views", help="Views rendered for features (default 40)."),
    trans_spacing: Optional[float] = TRANS_SPACING,
    camera_height: Optional[str] = CAMERA_HEIGHT,
    up: Optional[str] = UP,
    scale: Optional[float] = SCALE,
    scene: Optional[list[str]] = typer.Option(None, "--scene", help="Only these scenes (repeatable)."),
    line_files: bool = typer.Option(False, "--line-files", help="Use the dataset's 3D line files (pcd_line/) instead of "
                                    "extracting lines; a scene without a scan gets a lines-only map (features none)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Rebuild maps that are up to date."),
    device: str = typer.Option("cpu", "--device", help="cpu | cuda."),
    threads: int = threads_option(),
    ray: Optional[str] = ray_option(),
) -> None:
    """Build one map per scene of a dataset root, skipping maps that are up to date.

    With --ray, one Ray task per scene (one GPU each with --device cuda)."""


    if map_level is not None:
        datasets.check_map_level(map_level, "--map-level")
    check_threads(threads)
    check_device(device)
    build_options = dict(weights=str(weights) if weights else None, feature_extraction=extraction,
                         num_translations=num_trans, num_views=num_views, device=device, trans_spacing=trans_spacing,
                         camera_height=parse_band(camera_height, "--camera-height"), up=up, scale=scale)
    map_params.params_with(map_params.BuildParams(), features=features, **build_options).check()
    given_level, map_level = map_level, map_level or "room"
    ds = open_dataset_root(root, dataset, "ldlmap prepare ROOT", map_level=map_level)
    root, kind, label = Path(ds.root), ds.kind, dataset_label(ds)
    refuse_map_level(given_level, kind, label, root)
    _check_maps_folder(maps if maps is not None else root / "maps", maps is not None)
    if kind == "zind":
        if features not in (None, "none"):
            raise InputError(f"ZInD maps are built from room layouts and carry no features: --features {features} "
                             "is not possible (leave it out or use none)")
        if line_files:
            raise InputError("ZInD has no 3D line files: its maps are built from the room layouts")
        if (up or "auto").lower() not in ("auto", "z", "+z") or (scale is not None and scale != 1.0):
            raise InputError("ZInD maps are built metric and z-up from the room layouts: --up and --scale do not apply")
        ds.scenes()  # reads and validates every home's zind_data.json before anything is printed
        _print_warnings(w for home in ds.splits() for w in ds.home(home).warnings)
        console.print(f"ZInD: lines-only maps from the room layouts, one per {map_level} (features: none)")
    params = map_params.params_with(batch_prepare.default_params(kind),
                                    features=features or ("none" if kind == "zind" else "sift"), **build_options)
    options = dict(overwrite=overwrite, use_line_files=line_files, scenes=scene or None, map_level=map_level)
    if ray is not None:  # one Ray task per scene (ldlmap/batch/ray_prepare.py)

        with ray_cluster.ThroughputBar(console, "scenes") as bar:
            outcomes = ray_prepare.prepare_dataset_ray(root, kind, maps, params, progress=bar, address=ray, threads=threads,
                                           **options)
    else:
        set_threads(threads)
        outcomes = _prepare_with_progress(ds, root, kind, maps, params, scene, options)
    table = Table(title=f"maps of {root} ({label}" + (f", {map_level} level)" if kind == "zind" else ")"))
    for col in ("scene", "status", "map", "seconds", "note"):
        table.add_column(col)
    for o in outcomes:
        secs = f"{o.report.seconds['total']:.1f}" if o.report else "-"
        table.add_row(o.scene, o.status, str(o.map_path), secs, o.message)
    console.print(table)
    lines_only = [o.scene for o in outcomes if o.message == batch_prepare.LINES_ONLY_NOTE]
    if lines_only:
        console.print(f"{len(lines_only)} scene(s) without a scan, lines-only map(s) from their line files (features "
                      f"none): {', '.join(lines_only)}", soft_wrap=True)
    failed = [o for o in outcomes if o.status == "failed"]
    if failed:
        raise InputError(f"{len(failed)} of {len(outcomes)} scene(s) failed: " + "; ".join(f"{o.scene}: {o.message}" for o in failed))


def _print_warnings(lines) -> None:
    """Each line as a ``warning:`` on stderr."""
    for line in lines:
        err_console.print(f"[bold yellow]warning:[/] {line}", soft_wrap=True, highlight=False)


def _check_maps_folder(maps: Path, given: bool) -> None:
    """One line before any work when the maps cannot be written where they would go (a dataset
    folder is often read-only): where to put them instead."""


    existing = next((p for p in (maps, *maps.parents) if p.exists()), Path("."))
    if not (existing.is_dir() and os.access(existing, os.W_OK)):
        raise InputError(f"cannot write the maps into {maps} ({existing} is not a writable folder): "
                         + ("give another folder with --maps DIR" if given else
                            "the dataset folder is read-only; give a folder for them with --maps DIR "
                            "(and the same --maps to `ldlloc run`)"))


def _prepare_with_progress(ds, root: Path, kind: str, maps: Optional[Path], params, scene: Optional[list[str]],
                           options: dict) -> list:
    """``prepare_dataset`` on this machine, showing the scenes done and each build's running stage."""
    done_scenes: set[str] = set()
    with StageProgress(console, "maps", total=len(scene or ds.scenes()), unit="scenes") as bar:
        def progress(scene_name: str, stage: str, done: int, total: int) -> None:
            bar.stage(scene_name, stage, done, total)
            if stage in ("up-to-date", "failed") or (stage == "write" and done == total):
                done_scenes.add(scene_name)
                bar.job_done(len(done_scenes))

        return batch_prepare.prepare_dataset(root, kind, maps, params, progress=progress, **options)


if __name__ == "__main__":  # python3 -m ldlmap.cli
    app()
