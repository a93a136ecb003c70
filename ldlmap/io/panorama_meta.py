"""What a 360 camera writes into its JPEG panoramas: gravity (XMP GPano pose) and capture time.

``panorama_metadata(path) -> PanoramaMetadata(pitch_deg, roll_deg, heading_deg, time)``; each
field None when the photo does not say. Read with the standard library from the JPEG's APP1
segments: the XMP packet (XML, ``http://ns.adobe.com/xap/1.0/``) for Google's Photo Sphere
``GPano:PosePitchDegrees``, ``PoseRollDegrees``, ``PoseHeadingDegrees`` (Ricoh Theta, Insta360 and
others; attribute or element form), and the EXIF block for ``DateTimeOriginal`` (else the XMP's
``exif:DateTimeOriginal``, ``photoshop:DateCreated`` or ``xmp:CreateDate``). Why no library:
three attributes and one tag need a segment walk and an XML parse, and the readers on the
registry either pull more dependencies (Pillow's ``getxmp`` wants ``defusedxml``) or do not read
XMP. Python's expat refuses entity-expansion bombs, so a hostile packet fails with one line.

GPano's angles (its specification): pitch is the image centre's elevation above the horizon in
[-90, 90], roll turns the horizon counter-clockwise in the image as it grows, in (-180, 180],
heading the image centre's compass bearing in [0, 360). :func:`camera_up` turns pitch and roll
into the world's up axis seen in our camera frame (:mod:`ldlmap.core.geometry`: the image
centre looks along +x, +y left, +z up).
"""

from __future__ import annotations

import os
import re
import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

from ldlmap.core.errors import InputError, require_file

GPANO_NS = "http://ns.google.com/photos/1.0/panorama/"
XMP_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
EXIF_HEADER = b"Exif\x00\x00"
_TIME_KEYS = (("http://ns.adobe.com/exif/1.0/", "DateTimeOriginal"), ("http://ns.adobe.com/photoshop/1.0/", "DateCreated"),
              ("http://ns.adobe.com/xap/1.0/", "CreateDate"))
_BOUNDS = {"PosePitchDegrees": (-90.0, 90.0, "[-90, 90]"), "PoseRollDegrees": (-180.0, 180.0, "(-180, 180]"),
           "PoseHeadingDegrees": (0.0, 360.0, "[0, 360)")}


@dataclass(frozen=True)
class PanoramaMetadata:
    """A panorama's recorded gravity and capture time (None where the photo does not say)."""

    pitch_deg: float | None = None
    roll_deg: float | None = None
    heading_deg: float | None = None
    time: datetime | None = None

    @property
    def has_gravity(self) -> bool:
        return self.pitch_deg is not None and self.roll_deg is not None


def _segments(data: bytes, path: Path) -> list[bytes]:
    """The APP1 payloads of a JPEG file (up to its image data)."""
    if data[:2] != b"\xff\xd8":
        raise InputError(f"not a JPEG file (no SOI marker): {path}")
    out, i = [], 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            raise InputError(f"corrupt JPEG: no marker at byte {i}: {path}")
        marker = data[i + 1]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:  # markers without a length
            i += 2
            continue
        if marker in (0xDA, 0xD9):  # start of scan / end of image: no metadata after
            break
        (length,) = struct.unpack(">H", data[i + 2:i + 4])
        if length < 2 or i + 2 + length > len(data):
            raise InputError(f"corrupt JPEG: a segment runs past the end of the file: {path}")
        if marker == 0xE1:
            out.append(data[i + 4:i + 2 + length])
        i += 2 + length
    return out


def _exif_time(block: bytes) -> str | None:
    """EXIF ``DateTimeOriginal`` (tag 0x9003 of the Exif IFD) of an APP1 EXIF block, as text, with
    ``SubSecTimeOriginal`` (0x9291) as its fraction when present."""
    tiff = block[len(EXIF_HEADER):]
    if len(tiff) < 8 or tiff[:2] not in (b"II", b"MM"):
        return None
    e = "<" if tiff[:2] == b"II" else ">"

    def entries(offset: int):
        if offset + 2 > len(tiff):
            return
        (n,) = struct.unpack(e + "H", tiff[offset:offset + 2])
        for k in range(min(n, 512)):
            at = offset + 2 + 12 * k
            if at + 12 > len(tiff):
                return
            yield struct.unpack(e + "HHI4s", tiff[at:at + 12])

    (ifd0,) = struct.unpack(e + "I", tiff[4:8])
    exif = next((struct.unpack(e + "I", raw)[0] for tag, _, _, raw in entries(ifd0) if tag == 0x8769), None)
    if exif is None:
        return None
    texts = {}
    for tag, kind, count, raw in entries(exif):
        if tag in (0x9003, 0x9291) and kind == 2:  # DateTimeOriginal, SubSecTimeOriginal
            start = struct.unpack(e + "I", raw)[0] if count > 4 else None
            text = raw[:count] if start is None else tiff[start:start + count]
            texts[tag] = text.split(b"\x00")[0].decode("ascii", "replace").strip()
    if 0x9003 not in texts:
        return None
    sub = texts.get(0x9291, "")
    return texts[0x9003] + (f".{sub}" if sub.isdigit() else "")


def _parse_time(text: str, path: Path) -> datetime:
    """An EXIF (``YYYY:MM:DD HH:MM:SS``) or XMP (ISO 8601) time."""
    t = text.strip()
    try:
        if re.fullmatch(r"\d{4}:\d\d:\d\d \d\d:\d\d:\d\d(\.\d+)?", t):
            whole, _, frac = t.partition(".")
            return datetime.strptime(whole, "%Y:%m:%d %H:%M:%S") + timedelta(seconds=float(f"0.{frac or 0}"))
        return datetime.fromisoformat(t.replace("Z", "+00:00"))
    except ValueError:
        raise InputError(f"capture time {t!r} is not a date and time: {path}") from None


def _xmp_values(packet: bytes, path: Path) -> dict[tuple[str, str], str]:
    """``(namespace, name) -> text`` of the XMP packet's rdf:Description attributes and simple elements."""
    try:
        root = ET.fromstring(packet.decode("utf-8", "replace").strip().strip("\x00"))
    except ET.ParseError as exc:
        raise InputError(f"corrupt XMP packet ({exc}): {path}") from None
    out: dict[tuple[str, str], str] = {}
    for el in root.iter():
        for key, value in el.attrib.items():
            if key.startswith("{"):
                ns, name = key[1:].split("}", 1)
                out.setdefault((ns, name), value)
        if el.tag.startswith("{") and el.text and el.text.strip() and len(el) == 0:
            ns, name = el.tag[1:].split("}", 1)
            out.setdefault((ns, name), el.text.strip())
    return out


def _angle(values: dict, name: str, path: Path) -> float | None:
    text = values.get((GPANO_NS, name))
    if text is None:
        return None
    lo, hi, shown = _BOUNDS[name]
    try:
        v = float(text)
    except ValueError:
        raise InputError(f"XMP GPano:{name} is not a number ({text!r}): {path}") from None
    ok = np.isfinite(v) and lo <= v <= hi and not (name == "PoseRollDegrees" and v == -180.0) \
        and not (name == "PoseHeadingDegrees" and v == 360.0)
    if not ok:
        raise InputError(f"XMP GPano:{name} = {text} is outside {shown} degrees: {path}")
    return v


def panorama_metadata(path: str | os.PathLike) -> PanoramaMetadata:
    """The gravity (GPano pitch, roll, heading) and capture time recorded in a JPEG panorama.

    A PNG or other image has none (all None). One-line :class:`InputError` for a corrupt JPEG
    or XMP packet, angles that are not numbers or lie outside GPano's ranges, or a time that is
    not one. For walks: sort panoramas by ``.time`` (None last)."""
    p = require_file(path, "panorama")
    with open(p, "rb") as fh:
        head = fh.read(2)
        if head != b"\xff\xd8":
            return PanoramaMetadata()
        data = head + fh.read(1 << 20)  # metadata precedes the image data; 1 MiB holds any APP1 (64 kB each)
    values: dict = {}
    exif_time = None
    for seg in _segments(data, p):
        if seg.startswith(XMP_HEADER):
            values.update({k: v for k, v in _xmp_values(seg[len(XMP_HEADER):], p).items() if k not in values})
        elif seg.startswith(EXIF_HEADER) and exif_time is None:
            try:
                exif_time = _exif_time(seg)
            except struct.error:
                raise InputError(f"corrupt EXIF block: {p}") from None
    text = exif_time or next((values[k] for k in _TIME_KEYS if k in values), None)
    pitch, roll = _angle(values, "PosePitchDegrees", p), _angle(values, "PoseRollDegrees", p)
    return PanoramaMetadata(pitch, roll, _angle(values, "PoseHeadingDegrees", p),
                            _parse_time(text, p) if text else None)


def camera_up(pitch_deg: float, roll_deg: float) -> np.ndarray:
    """The world's up axis (unit, 3) in our camera frame for GPano pitch and roll.

    The camera turned into the world (heading aside) is ``Ry(-pitch) Rx(roll)``: pitch lifts the
    image centre (+x) towards +z, roll lifts the left (+y) towards +z, which turns the horizon
    counter-clockwise in the image. Up in the camera is its transpose applied to +z."""
    p, r = np.radians(float(pitch_deg)), np.radians(float(roll_deg))
    Ry = np.array([[np.cos(-p), 0.0, np.sin(-p)], [0.0, 1.0, 0.0], [-np.sin(-p), 0.0, np.cos(-p)]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(r), -np.sin(r)], [0.0, np.sin(r), np.cos(r)]])
    return (Ry @ Rx).T @ np.array([0.0, 0.0, 1.0])


def recorded_up(path: str | os.PathLike) -> np.ndarray | None:
    """The world's up axis in the camera frame as the panorama's XMP GPano pose records it, or
    None when it records no pitch and roll (the upright prior then bounds the tilt around level)."""
    meta = panorama_metadata(path)
    return camera_up(meta.pitch_deg, meta.roll_deg) if meta.has_gravity else None


def write_gpano(jpeg: bytes, pitch_deg: float | str, roll_deg: float | str, heading_deg: float | str | None = None,
                time: str | None = None) -> bytes:
    """``jpeg`` with an XMP packet holding GPano pose attributes (and ``exif:DateTimeOriginal``)
    inserted after its SOI marker: how a 360 camera's file looks, for tests."""
    attrs = [f'GPano:PosePitchDegrees="{pitch_deg}"', f'GPano:PoseRollDegrees="{roll_deg}"',
             'GPano:ProjectionType="equirectangular"']
    if heading_deg is not None:
        attrs.append(f'GPano:PoseHeadingDegrees="{heading_deg}"')
    if time is not None:
        attrs.append(f'exif:DateTimeOriginal="{time}"')
    xml = ('<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
           f'<rdf:Description rdf:about="" xmlns:GPano="{GPANO_NS}" xmlns:exif="http://ns.adobe.com/exif/1.0/" '
           + " ".join(attrs) + "/></rdf:RDF></x:xmpmeta>").encode()
    seg = XMP_HEADER + xml
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(seg) + 2) + seg + jpeg[2:]

