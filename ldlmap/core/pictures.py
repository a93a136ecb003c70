"""Pictures people would rather see than read: panoramas with lines drawn on them.

Colors by principal group (BGR for OpenCV): group 0 red, 1 green, 2 blue, none grey.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ldlmap.core.errors import InputError, atomic_file
from ldlmap.core.geometry import cam_from_world, normalize, pixel_from_bearing
from ldlmap.core.lazy import lazy_module
from ldlmap.io.imagefile import encode_image, image_comment

cv2 = lazy_module("cv2")

GROUP_COLORS_BGR = {0: (40, 40, 230), 1: (40, 180, 40), 2: (230, 90, 40), -1: (150, 150, 150),
                    # Atlanta frames of more than 3 directions: further horizontals
                    3: (30, 200, 230), 4: (200, 60, 200), 5: (200, 200, 40), 6: (20, 110, 240)}


GROUP_NAMES = {**{g: f"d{g}" for g in range(7)}, -1: "no group"}
BAND_BGR = (30, 30, 30)  # the caption band under a picture: white text on dark grey


def group_legend(principal: np.ndarray | None = None) -> list[tuple[tuple[int, int, int], str]]:
    """Legend entries (BGR colour, label) of the principal groups; given the map's principal
    directions (K, 3) (z up), each label says whether its direction is vertical, horizontal (within
    10 deg) or inclined, with its elevation (a sloped ceiling's)."""
    items = []
    for g in range(3 if principal is None else len(principal)):
        label = GROUP_NAMES[g]
        if principal is not None:
            rise = float(np.degrees(np.arcsin(min(abs(float(np.asarray(principal)[g][2])), 1.0))))
            label += " vertical" if rise >= 80.0 else " horizontal" if rise <= 10.0 else f" inclined {rise:.0f} deg"
        items.append((GROUP_COLORS_BGR[g], label))
    return items + [(GROUP_COLORS_BGR[-1], GROUP_NAMES[-1])]


def drawable_text(text: str) -> str:
    """``text`` as OpenCV's Hershey fonts draw it: ASCII, other bytes as ``\\xNN`` escapes (a file
    name that is not UTF-8 holds surrogates, which crash OpenCV's string conversion)."""
    try:
        data = text.encode("utf-8", "surrogateescape")
    except UnicodeEncodeError:
        data = text.encode("utf-8", "backslashreplace")
    return data.decode("ascii", "backslashreplace")


def caption_band(width: int, caption: str, items: list[tuple[tuple[int, int, int], str]], note: str = "",
                 scale: float = 1.0) -> np.ndarray:
    """A dark BGR band ``width`` pixels wide to put under a picture: ``caption`` on the first row,
    then a colour swatch and label per legend entry of ``items``, then ``note``; what does not fit
    in a row goes to the next."""
    font, size, thick = cv2.FONT_HERSHEY_SIMPLEX, 0.55 * scale, max(1, int(round(1.2 * scale)))
    pad, gap, swatch = int(8 * scale), int(18 * scale), int(26 * scale)
    caption, note = drawable_text(caption), drawable_text(note)
    items = [(color, drawable_text(label)) for color, label in items]
    text_h = cv2.getTextSize("Ag", font, size, thick)[0][1]
    row_h = text_h + int(12 * scale)

    def text_w(text: str) -> int:
        return cv2.getTextSize(text, font, size, thick)[0][0]

    tokens = [("text", w) for w in caption.split()] + [("break", None)] + [("swatch", it) for it in items] \
        + [("text", w) for w in note.split()]
    rows: list[list[tuple[int, str, object]]] = [[]]
    x = pad
    for kind, payload in tokens:
        if kind == "break":
            rows.append([])
            x = pad
            continue
        w = text_w(payload + " ") if kind == "text" else swatch + int(6 * scale) + text_w(payload[1]) + gap
        if x + w > width - pad and rows[-1]:  # wrap
            rows.append([])
            x = pad
        rows[-1].append((x, kind, payload))
        x += w
    band = np.full((len(rows) * row_h + pad, width, 3), BAND_BGR, np.uint8)
    for r, row in enumerate(rows):
        base = pad + r * row_h + text_h
        for x0, kind, payload in row:
            label = payload if kind == "text" else payload[1]
            if kind == "swatch":
                mid = base - text_h // 2
                cv2.line(band, (x0, mid), (x0 + swatch, mid), payload[0], max(3, int(4 * scale)), cv2.LINE_AA)
                x0 += swatch + int(6 * scale)
            cv2.putText(band, label, (x0, base), font, size, (255, 255, 255), thick, cv2.LINE_AA)
    return band


def with_caption(image_bgr: np.ndarray, caption: str, items: list[tuple[tuple[int, int, int], str]],
                 note: str = "") -> np.ndarray:
    """``image_bgr`` with a :func:`caption_band` under it (text scaled to the picture's width)."""
    width = image_bgr.shape[1]
    band = caption_band(width, caption, items, note, scale=max(1.0, width / 1400))
    return np.concatenate([image_bgr, band], axis=0)


def arc_polylines(arcs_cam: np.ndarray, width: int, height: int, samples: int = 48) -> list[np.ndarray]:
    """Pixel polylines of great-circle arcs (N, 2, 3), split where they cross the u seam."""
    arcs = np.asarray(arcs_cam, dtype=np.float64).reshape(-1, 2, 3)
    if len(arcs) == 0:
        return []
    t = np.linspace(0.0, 1.0, samples)[None, :, None]
    s, e = normalize(arcs[:, 0])[:, None], normalize(arcs[:, 1])[:, None]
    pts = normalize(s * (1 - t) + e * t)  # (N, S, 3): chord points projected to the sphere
    uv = pixel_from_bearing(pts, width, height)
    out = []
    for line in uv:  # one polyline per arc (drawing, not a hot path)
        jumps = np.nonzero(np.abs(np.diff(line[:, 0])) > width / 2)[0] + 1
        out.extend(p for p in np.split(line, jumps) if len(p) > 1)
    return out


def draw_arcs(image_bgr: np.ndarray, arcs_cam: np.ndarray, groups: np.ndarray | None = None,
              thickness: int = 2, color: tuple[int, int, int] | None = None) -> np.ndarray:
    """Draw arcs (camera frame) on a copy of an equirectangular BGR image."""
    img = np.ascontiguousarray(image_bgr).copy()
    h, w = img.shape[:2]
    groups = np.full(len(arcs_cam), -1) if groups is None else np.asarray(groups)
    arcs = np.asarray(arcs_cam).reshape(-1, 2, 3)
    for i in range(len(arcs)):  # per arc, for drawing
        c = color or GROUP_COLORS_BGR.get(int(groups[i]), GROUP_COLORS_BGR[-1])
        for pl in arc_polylines(arcs[i:i + 1], w, h):
            cv2.polylines(img, [np.round(pl).astype(np.int32)], False, c, thickness, cv2.LINE_AA)
    return img


def project_lines(lines_world: np.ndarray, rot_cam_from_world: np.ndarray, center: np.ndarray) -> np.ndarray:
    """3D segments (L, 2, 3) as camera-frame arcs seen from pose ``(R, t)``."""
    return normalize(cam_from_world(np.asarray(lines_world).reshape(-1, 2, 3), rot_cam_from_world, center))


# Picture formats OpenCV's imwrite writes from the extension alone (lower case).
PICTURE_SUFFIXES: tuple[str, ...] = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")


def check_picture_path(path: str | Path, option: str = "picture") -> Path:
    """``path`` as a Path when its extension names a format in :data:`PICTURE_SUFFIXES`, else a
    one-line :class:`InputError` naming ``option`` (call it before any work is done)."""
    p = Path(path)
    if p.suffix.lower() not in PICTURE_SUFFIXES:
        raise InputError(f"{option} {p}: cannot write {p.suffix or 'a file without extension'} pictures; "
                         f"use {', '.join(PICTURE_SUFFIXES)}")
    return p


PICTURE_MARK = "written by ldl: a picture of ldlmap / ldlloc"  # embedded in our JPEGs and PNGs


def is_own_picture(path: str | Path) -> bool:
    """Whether ``path`` is a picture this toolkit wrote (a JPEG or PNG carrying :data:`PICTURE_MARK`):
    one a later run may replace without ``--overwrite``. Other formats carry no mark."""
    return image_comment(path) == PICTURE_MARK


def refuse_replacing_pictures(paths: list[Path], overwrite: bool, option: str) -> None:
    """Before any work: one line when a picture of ``paths`` would replace a file this toolkit did
    not write (:func:`is_own_picture`) and ``overwrite`` is not set, or when two of them are the
    same file (one picture would replace the other's)."""
    seen: dict[str, Path] = {}
    for p in paths:
        key = os.path.normcase(os.path.abspath(p))
        if key in seen:
            raise InputError(f"{option}: two pictures would be the same file {p}")
        seen[key] = p
    for p in paths:
        if Path(p).is_dir():
            raise InputError(f"{option}: picture {p} is a folder")
        if not overwrite and os.path.lexists(p) and not is_own_picture(p):
            raise InputError(f"{option}: {p} exists and is not a picture of ldlloc (ldlloc's pictures carry a mark "
                             "in the file); use --overwrite to replace it, or another name")


def picture_file(folder: str | Path, name: str, suffix: str = ".jpg") -> Path:
    """The picture of ``name`` (a query's name, ``/``-separated) inside ``folder``, never outside
    it: ``.`` and empty parts are dropped and each ``..`` part becomes ``%2e%2e`` (a name, not a
    step up), so distinct names give distinct files."""
    parts = [("%2e%2e" if part == ".." else part) for part in str(name).split("/")
             if part not in ("", ".")]
    return Path(folder).joinpath(*(parts or ["_"])).with_name((parts or ["_"])[-1] + suffix)


def write_picture(path: str | Path, image_bgr: np.ndarray, quality: int = 90) -> Path:
    """Write a BGR picture atomically in the format its extension names (JPEG / WebP at ``quality``),
    through Python's file I/O (any file name), marked as ours in a JPEG or PNG (:func:`is_own_picture`)."""
    p = check_picture_path(path)
    with atomic_file(p) as tmp:
        try:
            data = encode_image(image_bgr, p.suffix, quality, comment=PICTURE_MARK)
        except ValueError as exc:
            raise InputError(f"could not write picture {p}: {exc}") from None
        with open(tmp, "wb") as f:
            f.write(data)
    return p
