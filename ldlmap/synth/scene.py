"""Build the textured triangle mesh of a scene spec (floor at z = 0, z up, metres).

Parts (each a planar-faced piece; ``SceneMesh.tri_part`` numbers them):

* room shell: floor polygon (ear clipping, non-convex OK), ceiling (flat, or planar pieces and
  steps: :mod:`ldlmap.synth.ceiling`), one planar face per wall up to the ceiling above it; normals
  point into the room;
* door / window frames: closed prisms standing ``FRAME_DEPTH`` out of the wall around a
  textured panel (a quad ``PANEL_OFFSET`` in front of the wall); doors have no bottom bar; an
  open door (a walk's: ``build_scene(open_doors=...)``) has no panel, a notch cut in its wall and a
  reveal (jambs, lintel, threshold) into the wall's thickness;
* posters: single quads ``POSTER_OFFSET`` in front of the wall;
* furniture: closed boxes with outward normals; tables = top slab + 4 legs, shelves = sides,
  back and boards, cabinets = plinth + body + top, sofas = base + backrest + armrests. Parts are
  at least 4 cm thick, and touching parts are inset so that no two faces of different parts
  continue each other in one plane (no fake edges at part junctions).

Every planar face gets its own rectangle in one texture atlas at about ``TEXEL_M`` per texel.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import numpy as np

from ldlmap.core import polygon as pg
from ldlmap.core.errors import InputError
from ldlmap.synth import textures as tx
from ldlmap.synth.ceiling import ceiling_pieces, ceiling_profile, step_faces, wall_loop
from ldlmap.synth.spec import (FRAME_DEPTH, FRAME_WIDTH, PANEL_OFFSET, POSTER_OFFSET, ObjectSpec,
                               SceneSpec, validate_spec)
from ldlmap.synth.types import SceneMesh

TEXEL_M = 0.012  # m per atlas texel (grown when the atlas would exceed MAX_ATLAS)
MAX_ATLAS = 4096  # px, largest atlas side


@dataclass
class _Face:
    """A planar polygon face: loop counter-clockwise seen from its front (normal side)."""

    verts: np.ndarray  # (K, 3)
    uv: np.ndarray  # (K, 2) metres in the face plane (u right, v up seen from the front)
    tris: np.ndarray  # (T, 3) indices into verts
    texture: str  # material name, or "door" / "window" / "poster"
    obj: int  # -1 shell, else object index
    part: int  # solid index
    tone: float = 1.0
    base: np.ndarray | None = None  # base color (shared by faces of one surface class / object)
    tex_seed: int = 0


def _newell(loop: np.ndarray) -> np.ndarray:
    q = np.roll(loop, -1, axis=0)
    n = np.array([np.sum((loop[:, 1] - q[:, 1]) * (loop[:, 2] + q[:, 2])),
                  np.sum((loop[:, 2] - q[:, 2]) * (loop[:, 0] + q[:, 0])),
                  np.sum((loop[:, 0] - q[:, 0]) * (loop[:, 1] + q[:, 1]))])
    return n / np.linalg.norm(n)


def _face(loop: np.ndarray, normal: np.ndarray, **kw) -> _Face:
    """A face from a planar loop (any orientation): reordered to face ``normal``, triangulated."""
    loop = np.asarray(loop, dtype=np.float64)
    n = _newell(loop)
    if np.dot(n, normal) < 0:
        loop, n = loop[::-1].copy(), -n
    up = np.array([0.0, 0.0, 1.0])
    if abs(n[2]) > 0.9:  # horizontal face: u along the first edge
        u = loop[1] - loop[0]
        u = u - n * np.dot(u, n)
    else:  # vertical-ish face: u horizontal, v up
        u = np.cross(up, n)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    rel = loop - loop[0]
    uv = np.stack([rel @ u, rel @ v], axis=1)
    tris = np.array([[0, 1, 2], [0, 2, 3]]) if len(loop) == 4 else pg.triangulate_polygon(uv)
    return _Face(loop, uv, tris, **kw)


def _box_faces(corner_lo: np.ndarray, corner_hi: np.ndarray, frame: np.ndarray, origin: np.ndarray,
               **kw) -> list[_Face]:
    """Six outward faces of the box [lo, hi] given in a local frame (rows of ``frame`` = local axes)."""
    lo, hi = np.asarray(corner_lo, float), np.asarray(corner_hi, float)
    bits = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64)
    local = lo + bits * (hi - lo)
    world = origin + local @ frame
    quads = {(-1, 0): (0, 4, 6, 2), (1, 0): (1, 3, 7, 5), (-1, 1): (0, 1, 5, 4), (1, 1): (2, 6, 7, 3),
             (-1, 2): (0, 2, 3, 1), (1, 2): (4, 5, 7, 6)}
    faces = []
    for (sign, axis), idx in quads.items():
        faces.append(_face(world[list(idx)], sign * frame[axis], **kw))
    return faces


def _frame_axes(yaw_deg: float) -> np.ndarray:
    a = math.radians(yaw_deg)
    return np.array([[math.cos(a), math.sin(a), 0.0], [-math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])


def _object_parts(obj: ObjectSpec) -> list[tuple[tuple[float, float, float], tuple[float, float, float]]]:
    """Boxes (lo, hi) in the object frame (x width, y depth with the front at -y, z up)."""
    sx, sy, sz = obj.size
    hx, hy = sx / 2, sy / 2
    if obj.kind == "table":
        t, leg, inset = min(0.06, sz * 0.2), min(0.08, sx / 4, sy / 4), min(0.05, sx / 10, sy / 10)
        parts = [((-hx, -hy, sz - t), (hx, hy, sz))]
        for cx in (-1, 1):
            for cy in (-1, 1):
                x0 = cx * (hx - inset) - (leg if cx > 0 else 0)
                y0 = cy * (hy - inset) - (leg if cy > 0 else 0)
                parts.append(((x0, y0, 0.0), (x0 + leg, y0 + leg, sz - t)))
        return parts
    if obj.kind == "shelf":
        side, back, board = 0.05, 0.04, 0.05
        xi = hx - side
        parts = [((-hx, -hy, 0.0), (-xi, hy, sz)), ((xi, -hy, 0.0), (hx, hy, sz)),
                 ((-xi, hy - back - 0.01, 0.0), (xi, hy - 0.01, sz - 0.03))]
        n_mid = max(1, int((sz - 0.2) / 0.38))
        levels = np.linspace(0.06, sz - 0.03 - board, n_mid + 2)
        for z0 in levels:
            parts.append(((-xi, -hy + 0.02, float(z0)), (xi, hy - back - 0.01, float(z0) + board)))
        return parts
    if obj.kind == "cabinet":
        plinth, top = 0.08, 0.04
        return [((-hx + 0.05, -hy + 0.05, 0.0), (hx - 0.05, hy - 0.05, plinth)),
                ((-hx, -hy, plinth), (hx, hy, sz - top)),
                ((-hx - 0.02, -hy - 0.02, sz - top), (hx + 0.02, hy - 0.01, sz))]
    if obj.kind == "sofa":
        seat = min(0.45, 0.55 * sz)
        back_d, arm_w = min(0.22, sy * 0.3), min(0.18, sx * 0.15)
        arm_h = min(0.22, (sz - seat) * 0.6)
        yb = hy - 0.03 - back_d
        return [((-hx, -hy, 0.0), (hx, hy, seat)),
                ((-hx + 0.03, yb, seat), (hx - 0.03, hy - 0.03, sz)),
                ((-hx + 0.03, -hy + 0.03, seat), (-hx + 0.03 + arm_w, yb, seat + arm_h)),
                ((hx - 0.03 - arm_w, -hy + 0.03, seat), (hx - 0.03, yb, seat + arm_h))]
    return [((-hx, -hy, 0.0), (hx, hy, sz))]  # box


def _seed(*items: object) -> int:
    return zlib.crc32(repr(items).encode()) & 0x7FFFFFFF


def _notched(loop: np.ndarray, origin: np.ndarray, t: np.ndarray,
             doors: list[tuple[float, float, float]]) -> np.ndarray:
    """A wall's loop (:func:`ldlmap.synth.ceiling.wall_loop`: its floor edge first, from xy ``origin``
    along unit xy ``t``) with an open door's notch cut up from its floor edge for each ``(start, end,
    top)`` along the wall (in order)."""
    if not doors:
        return loop
    o, u = np.array([origin[0], origin[1], 0.0]), np.array([t[0], t[1], 0.0])
    cut = [o + u * s + np.array([0.0, 0.0, z]) for s0, s1, top in doors
           for s, z in ((s0, 0.0), (s0, top), (s1, top), (s1, 0.0))]
    return np.concatenate([loop[:1], np.asarray(cut), loop[1:]])


def _reveal_faces(origin: np.ndarray, t: np.ndarray, n: np.ndarray, s0: float, s1: float, top: float, depth: float,
                  spec: SceneSpec, part: int, j: int) -> list[_Face]:
    """An open door's reveal on its room's side: the jambs, lintel and threshold from the wall's face
    ``depth`` into the wall (half the wall between two rooms: with the neighbour's, the whole)."""
    up = np.array([0.0, 0.0, 1.0])

    def at(s: float, d: float, z: float) -> np.ndarray:
        return origin + t * s - n * d + up * z

    sides = [([at(s0, 0, 0), at(s0, 0, top), at(s0, depth, top), at(s0, depth, 0)], t, spec.wall_material),
             ([at(s1, 0, 0), at(s1, 0, top), at(s1, depth, top), at(s1, depth, 0)], -t, spec.wall_material),
             ([at(s0, 0, top), at(s1, 0, top), at(s1, depth, top), at(s0, depth, top)], -up, spec.wall_material),
             ([at(s0, 0, 0), at(s1, 0, 0), at(s1, depth, 0), at(s0, depth, 0)], up, spec.floor_material)]
    return [_face(np.array(q), nrm, texture=mat, obj=-1, part=part, tex_seed=_seed(spec.seed, "reveal", j, m))
            for m, (q, nrm, mat) in enumerate(sides)]


def _collect_faces(spec: SceneSpec, open_doors: tuple[int, ...] = (), reveal_m: float = 0.0) -> list[_Face]:
    rng = np.random.default_rng([spec.seed, 17])
    fp = np.asarray(spec.footprint, dtype=np.float64)
    k = len(fp)
    h = spec.ceiling_height
    faces: list[_Face] = []
    part = 0
    # Room shell (one part): floor, ceiling, walls.
    wall_base = tx.pick_base(spec.wall_material, rng)
    floor = np.column_stack([fp, np.zeros(k)])
    faces.append(_face(floor, np.array([0, 0, 1.0]), texture=spec.floor_material, obj=-1, part=part,
                       tex_seed=_seed(spec.seed, "floor")))
    profile = ceiling_profile(spec.ceiling, fp, h)
    pieces = ceiling_pieces(profile, fp) + step_faces(profile, fp)
    # Pieces of one ceiling share a colour (its own stream: box rooms keep their draws).
    ceil_base = tx.pick_base(spec.ceiling_material, np.random.default_rng([spec.seed, 18])) if len(pieces) > 1 else None
    for j, (loop, normal) in enumerate(pieces):
        faces.append(_face(loop, normal, texture=spec.ceiling_material, obj=-1, part=part, base=ceil_base,
                           tex_seed=_seed(spec.seed, "ceiling", j) if j else _seed(spec.seed, "ceiling")))
    # Walls alternate in tone at corners; the facets of a curved wall (turning < 20 deg) keep one tone.
    turn = pg.corner_turns_deg(fp)
    group = np.concatenate([[0], np.cumsum(turn[1:] >= 20.0)])
    tones = 1.0 + 0.07 * np.where(group % 2 == 0, 1.0, -1.0) + rng.uniform(-0.02, 0.02, k)[group]
    for i in range(k):
        a, b = fp[i], fp[(i + 1) % k]
        t = (b - a) / np.linalg.norm(b - a)
        inward = np.array([-t[1], t[0], 0.0])
        doors = sorted((op.offset, op.offset + op.width, op.height) for j, op in enumerate(spec.openings)
                       if j in open_doors and op.wall == i)
        faces.append(_face(_notched(wall_loop(profile, a, b), a, t, doors), inward, texture=spec.wall_material,
                           obj=-1, part=part, tone=float(tones[i]), base=wall_base,
                           tex_seed=_seed(spec.seed, "wall", i)))
    part += 1

    def wall_frame(wall: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        a, b = fp[wall], fp[(wall + 1) % k]
        t = (b - a) / np.linalg.norm(b - a)
        return np.array([a[0], a[1], 0.0]), np.array([t[0], t[1], 0.0]), np.array([-t[1], t[0], 0.0])

    for j, op in enumerate(spec.openings):
        origin, t, n = wall_frame(op.wall)
        s0, s1, z0, z1 = op.offset, op.offset + op.width, op.sill, op.sill + op.height
        fw = FRAME_WIDTH
        if op.kind == "door":  # U-shaped profile, open at the floor
            prof = [(s0 - fw, 0.0), (s0, 0.0), (s0, z1), (s1, z1), (s1, 0.0), (s1 + fw, 0.0), (s1 + fw, z1 + fw),
                    (s0 - fw, z1 + fw)]
            rings = [np.array(prof)]
        else:  # rectangular ring
            rings = [np.array([(s0 - fw, z0 - fw), (s1 + fw, z0 - fw), (s1 + fw, z1 + fw), (s0 - fw, z1 + fw)]),
                     np.array([(s0, z0), (s1, z0), (s1, z1), (s0, z1)])]
        frame_base = tx.pick_base("painted", rng) * 0.3 + 0.65  # light painted frames
        kw = dict(texture="painted", obj=-1, part=part, base=frame_base)
        faces += _prism_faces(rings, origin, t, n, FRAME_DEPTH, kw, _seed(spec.seed, "frame", j))
        part += 1
        if j in open_doors:  # a doorway: no panel, the reveal into the wall
            if reveal_m > 0:
                faces += _reveal_faces(origin, t, n, s0, s1, z1, reveal_m, spec, part, j)
        else:
            panel = np.array([origin + t * s + np.array([0, 0, z]) + n * PANEL_OFFSET
                              for s, z in [(s0, z0), (s1, z0), (s1, z1), (s0, z1)]])
            faces.append(_face(panel, n, texture=op.kind, obj=-1, part=part, tex_seed=_seed(spec.seed, "panel", j)))
        part += 1
    for j, po in enumerate(spec.posters):
        origin, t, n = wall_frame(po.wall)
        quad = np.array([origin + t * s + np.array([0, 0, z]) + n * POSTER_OFFSET
                         for s, z in [(po.offset, po.bottom), (po.offset + po.width, po.bottom),
                                      (po.offset + po.width, po.bottom + po.height), (po.offset, po.bottom + po.height)]])
        faces.append(_face(quad, n, texture="poster", obj=-1, part=part, tex_seed=_seed(spec.seed, "poster", j)))
        part += 1
    for i, obj in enumerate(spec.objects):
        axes = _frame_axes(obj.yaw_deg)
        origin = np.array([obj.center[0], obj.center[1], 0.0])
        obj_rng = np.random.default_rng([spec.seed, 1000 + i])
        base = tx.pick_base(obj.material, obj_rng)
        for lo, hi in _object_parts(obj):
            faces += _box_faces(np.array(lo), np.array(hi), axes, origin, texture=obj.material, obj=i, part=part,
                                base=base, tone=float(obj_rng.uniform(0.9, 1.05)),
                                tex_seed=_seed(spec.seed, "object", i, lo, hi))
            part += 1
    return faces


def _prism_faces(rings: list[np.ndarray], origin: np.ndarray, t: np.ndarray, n: np.ndarray, depth: float,
                 kw: dict, seed: int) -> list[_Face]:
    """Closed prism of a wall-plane profile (simple polygon, or outer + inner rectangle) extruded along n."""
    up = np.array([0.0, 0.0, 1.0])

    def lift(p2: np.ndarray, d: float) -> np.ndarray:
        return origin + p2[:, :1] * t + p2[:, 1:2] * up + n * d

    faces: list[_Face] = []
    outer = rings[0] if pg.signed_area(rings[0]) > 0 else rings[0][::-1]
    loops = [outer]
    if len(rings) > 1:
        inner = rings[1] if pg.signed_area(rings[1]) < 0 else rings[1][::-1]
        loops.append(inner)
        # Front/back of the ring: one quad per side between matching outer/inner corners.
        o, q = outer, inner[::-1]  # both counter-clockwise, corners aligned (rectangles from the same start)
        for m in range(4):
            quad = np.array([o[m], o[(m + 1) % 4], q[(m + 1) % 4], q[m]])
            faces.append(_face(lift(quad, depth), n, tex_seed=seed + m, **kw))
            faces.append(_face(lift(quad, 0.0), -n, tex_seed=seed + 10 + m, **kw))
    else:
        faces.append(_face(lift(outer, depth), n, tex_seed=seed, **kw))
        faces.append(_face(lift(outer, 0.0), -n, tex_seed=seed + 10, **kw))
    for loop in loops:
        for m in range(len(loop)):
            p, q2 = loop[m], loop[(m + 1) % len(loop)]
            e = q2 - p
            out2 = np.array([e[1], -e[0]])  # right of a counter-clockwise edge = away from the material
            out3 = out2[0] * t + out2[1] * up
            quad = np.array([p, q2, q2, p])
            verts = np.concatenate([lift(quad[:2], 0.0), lift(quad[2:], depth)])
            faces.append(_face(verts, out3, tex_seed=seed + 20 + m, **kw))
    return faces


def _texture_for(face: _Face, h: int, w: int, texel: float) -> np.ndarray:
    rng = np.random.default_rng(face.tex_seed)
    if face.texture == "poster":
        return tx.poster_texture(h, w, rng)
    if face.texture == "door":
        return tx.door_texture(h, w, texel, rng)
    if face.texture == "window":
        return tx.window_texture(h, w, texel, rng)
    return tx.material_texture(face.texture, h, w, texel, rng, tone=face.tone, base=face.base)


def build_scene(spec: SceneSpec, texel_m: float = TEXEL_M, open_doors: tuple[int, ...] = (),
                reveal_m: float = 0.0) -> SceneMesh:
    """The textured mesh of ``spec`` (validated first); see the module docstring for the parts.
    ``open_doors``: the openings (doors) standing open, cut through their wall with no panel, with a
    reveal ``reveal_m`` deep (a walk's rooms: the person walking through opened them)."""
    validate_spec(spec)
    bad = [j for j in open_doors if not 0 <= j < len(spec.openings) or spec.openings[j].kind != "door"]
    if bad:
        raise InputError(f"open doors must be door openings of the spec, got {bad}")
    faces = _collect_faces(spec, tuple(open_doors), float(reveal_m))
    # Atlas layout: one rectangle per face, shrinking the density until it fits.
    uv_min = np.array([f.uv.min(axis=0) for f in faces])
    uv_ext = np.array([np.ptp(f.uv, axis=0) for f in faces])
    texel = texel_m
    while True:
        sizes = np.column_stack([np.ceil(uv_ext[:, 1] / texel) + 1, np.ceil(uv_ext[:, 0] / texel) + 1]).astype(np.int64)
        sizes = np.maximum(sizes, 2)
        try:
            offsets, ah, aw = tx.pack_rectangles(sizes, pad=2, max_side=MAX_ATLAS)
            break
        except ValueError:
            texel *= 1.25
    atlas = np.zeros((ah, aw, 3), dtype=np.uint8)
    verts, tris, uvs, objs, parts = [], [], [], [], []
    nv = 0
    for f, (r0, c0), (hh, ww), mn in zip(faces, offsets, sizes, uv_min):
        img = _texture_for(f, hh, ww, texel)
        atlas[r0:r0 + hh, c0:c0 + ww] = img
        # Dilate the borders by the padding so that bilinear lookups never see black.
        atlas[r0 - 2:r0, c0:c0 + ww] = img[:1]
        atlas[r0 + hh:r0 + hh + 2, c0:c0 + ww] = img[-1:]
        atlas[r0 - 2:r0 + hh + 2, c0 - 2:c0] = atlas[r0 - 2:r0 + hh + 2, c0:c0 + 1]
        atlas[r0 - 2:r0 + hh + 2, c0 + ww:c0 + ww + 2] = atlas[r0 - 2:r0 + hh + 2, c0 + ww - 1:c0 + ww]
        col = c0 + (f.uv[:, 0] - mn[0]) / texel + 0.5
        row = r0 + (f.uv[:, 1].max() - f.uv[:, 1]) / texel + 0.5
        st = np.stack([col / aw, 1.0 - row / ah], axis=1)
        verts.append(f.verts)
        tris.append(f.tris + nv)
        uvs.append(st[f.tris])
        objs.append(np.full(len(f.tris), f.obj, dtype=np.int32))
        parts.append(np.full(len(f.tris), f.part, dtype=np.int32))
        nv += len(f.verts)
    boxes = []
    for obj in spec.objects:
        axes = _frame_axes(obj.yaw_deg)
        sx, sy, sz = obj.size
        bits = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64)
        local = np.array([-sx / 2, -sy / 2, 0.0]) + bits * np.array([sx, sy, sz])
        boxes.append(np.array([obj.center[0], obj.center[1], 0.0]) + local @ axes)
    mesh = SceneMesh(
        vertices=np.concatenate(verts),
        triangles=np.concatenate(tris).astype(np.int64),
        tri_uvs=np.concatenate(uvs).astype(np.float32),
        atlas=atlas,
        tri_object=np.concatenate(objs),
        footprint=np.asarray(spec.footprint, dtype=np.float64),
        ceiling_height=float(spec.ceiling_height),
        name=spec.name,
        object_boxes=boxes,
        tri_part=np.concatenate(parts),
    )
    return mesh
