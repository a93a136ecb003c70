"""``ldlloc localize MAP PANO``: one panorama against one map, printed readably or as the JSON of
its record (:func:`ldlloc.record.printed_record`)."""

from __future__ import annotations

import json
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import typer

from ldlloc.batch.accuracy import THRESHOLDS, within_threshold
from ldlloc.batch.images import IMAGES_SPLIT
from ldlloc.batch.run import write_query_picture
from ldlloc.commands.options import localize_params
from ldlloc.pipeline import Localization, Localizer, load_image, rotation_prior_name
from ldlloc.record import QueryResult, failed_record, printed_failure, printed_record, record_of
from ldlloc.visualize import localization_caption
from ldlmap.core.cli_common import check_device, check_threads, console, import_heavy, set_threads
from ldlmap.core.errors import LdlError, refuse_overwriting_inputs, require_file
from ldlmap.core.pictures import check_picture_path, refuse_replacing_pictures
from ldlmap.datasets import read_pose_file
from ldlmap.io.panorama_meta import recorded_up
from ldlmap.map.contents import LdlMap
from ldlmap.map.mapfile import read_map


def localize(map_path: Path, pano: Path, as_json: bool, gt: Path | None, device: str, method: dict,
             vis: Path | None, overwrite: bool, threads: int) -> None:
    """The command (its options: :func:`ldlloc.cli.localize`); ``method``: the keyword arguments of
    :func:`~ldlloc.commands.options.localize_params`."""
    params = localize_params(**method)
    check_threads(threads)
    if vis is not None:
        check_picture_path(vis, "--vis")
        refuse_overwriting_inputs([map_path, pano, gt, method["weights"]], [vis])
        refuse_replacing_pictures([vis], overwrite, "--vis")
    truth = read_pose_file(gt) if gt is not None else None
    img = load_image(pano)
    check_device(device)
    m, loading = read_map_while_importing(map_path, threads)
    tick = time.perf_counter()
    localizer = Localizer(m, params, device)
    loading["setup"] = time.perf_counter() - tick
    up = None
    if params.max_tilt_deg is not None:  # the upright prior around the camera's own gravity (XMP GPano) when recorded
        up = recorded_up(pano)
    try:
        loc = localizer.localize(img, camera_up=up)
    except LdlError as exc:  # the panorama could not be localized (too few lines, ...): a failed result
        if not as_json:
            raise
        failed = failed_record(str(pano), map_path.stem, IMAGES_SPLIT, pano.stem, str(exc), {},
                               rotation_prior_name(params.max_tilt_deg), map=str(map_path))
        typer.echo(json.dumps(printed_failure(failed), indent=1))
        raise typer.Exit(1) from None
    rec = record_of(loc, str(pano), map_path.stem, IMAGES_SPLIT, pano.stem, truth=truth, map=str(map_path))
    errors = None
    if truth is not None:  # the dataset's frame is the map's input frame: compared in the map's, as `run` does
        errors = {"t_error_m": rec.t_error_m, "r_error_deg": rec.r_error_deg,
                  "localized": within_threshold(rec.t_error_m, rec.r_error_deg), "gt": str(gt)}
    out = printed_record(rec, loc.num_lines, loading, errors)
    if vis is not None:  # a picture that cannot be written is a warning: the result stands
        shown_errors = (rec.t_error_m, rec.r_error_deg) if truth is not None else None
        out["picture_error"] = write_query_picture(img, loc, m, vis, localization_caption(pano.name, loc, shown_errors))
    if as_json:
        typer.echo(json.dumps(out, indent=1))
        return
    print_localization(pano, loc, rec, loading, errors, gt)
    if vis is not None and out["picture_error"] is None:
        console.print(f"wrote {vis}", soft_wrap=True)
    elif vis is not None:
        console.print(f"[yellow]warning:[/] picture {vis} not written ({out['picture_error']})", soft_wrap=True)


def read_map_while_importing(map_path: Path, threads: int) -> tuple[LdlMap, dict[str, float]]:
    """The map (without its cloud), read in a thread while torch is imported: h5py decompresses
    with the GIL released for most of the read, so on an idle machine it costs no extra time.
    Returns the map and ``{"read_map": seconds the read took, "wait_map": seconds waited for it
    after the imports}``."""
    import_heavy("h5py")  # here, not in the thread, to keep the two imports apart
    require_file(map_path, "map")  # a missing map is said at once, not after the imports

    def read() -> tuple[LdlMap, float]:
        tick = time.perf_counter()
        return read_map(map_path, load_cloud=False), time.perf_counter() - tick

    with ThreadPoolExecutor(1) as pool:
        reading = pool.submit(read)
        import_heavy("torch", "cv2")
        set_threads(threads)
        tick = time.perf_counter()
        m, seconds = reading.result()
    return m, {"read_map": seconds, "wait_map": time.perf_counter() - tick}


def print_localization(pano: Path, loc: Localization, rec: QueryResult, loading: dict, errors: dict | None,
                       gt: Path | None) -> None:
    """The readable result of `localize`: status, pose, counts and seconds, errors against ``--gt``."""
    R, t = loc.rot_cam_from_world, loc.center
    console.print(f"[bold]{pano.name}[/]: {loc.status}" + (f" ({loc.message})" if loc.message else ""), soft_wrap=True)
    console.print(f"t = [{t[0]:.4f}, {t[1]:.4f}, {t[2]:.4f}] m (camera centre, world)", soft_wrap=True)
    console.print("R (world to camera) =\n" + "\n".join("  [" + ", ".join(f"{x: .6f}" for x in row) + "]" for row in R))
    if rec.input_frame is not None:  # maps built from another frame (SfM): the pose there too
        ti = rec.input_frame["t"]
        console.print(f"in the map's input frame: t = [{ti[0]:.4f}, {ti[1]:.4f}, {ti[2]:.4f}] (input units), "
                      "R: see --json (input_frame)", soft_wrap=True)
    console.print(f"{loc.num_lines} lines, {loc.num_rotations} candidate rotations ({loc.rotation_prior}), "
                  f"{loc.num_matches} matches, "
                  f"{loc.num_inliers} inliers; " + ", ".join(f"{k} {v:.3f} s" for k, v in loc.seconds.items())
                  + f" (map read {loading['read_map']:.3f} s beside the imports, setup {loading['setup']:.3f} s)",
                  soft_wrap=True)
    print_verdict(loc)
    if errors is not None:
        _, t_max, r_max = THRESHOLDS[1]
        ok = "[green]localized[/] (within" if errors["localized"] else "[yellow]not localized[/] (not within"
        console.print(f"error against {gt.name}: {errors['t_error_m']:.4f} m, {errors['r_error_deg']:.3f} deg: "
                      f"{ok} {t_max:g} m / {r_max:g} deg)", soft_wrap=True)


def print_verdict(loc: Localization) -> None:
    """The confidence line of `localize` and, for each competing pose, where it is and why."""
    color = {"confident": "green", "ambiguous": "yellow", "failed": "red"}.get(loc.verdict or "", "white")
    console.print(f"confidence {loc.confidence:.2f}: [{color}]{loc.verdict}[/]"
                  + (f", {len(loc.competitors)} competing pose(s):" if loc.competitors else ""), soft_wrap=True)
    for c in loc.competitors:
        t = c["t"]
        loss = "" if c.get("loss") is None else f", search loss {c['loss']:.1f}"
        console.print(f"  {c['why']}: t = [{t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}]{loss}", soft_wrap=True)
