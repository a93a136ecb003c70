"""Procedural textures (vectorized numpy + OpenCV resizes), deterministic from a seed.

Every material mixes multi-scale noise (fBm), a structured pattern (grain, planks, bricks,
tiles, weave) and sparse spots, so that panoramas have local features for SIFT; base colors keep
walls light, floors darker and ceilings near white so that structural edges stay visible.

Textures are (h, w, 3) uint8 RGB images whose row 0 is the *top* of the surface (largest ``t``
texture coordinate); ``texel_m`` is the size of one texel in metres, so patterns have a
physical scale independent of the surface size.
"""

from __future__ import annotations

import numpy as np

from ldlmap.core.lazy import lazy_module

cv2 = lazy_module("cv2")

# Base colors (RGB in [0, 1]) per material; a surface picks one and jitters it.
PALETTES: dict[str, list[tuple[float, float, float]]] = {
    "plaster": [(0.86, 0.83, 0.76), (0.80, 0.84, 0.86), (0.84, 0.86, 0.78), (0.88, 0.80, 0.74)],
    "wallpaper": [(0.82, 0.78, 0.66), (0.72, 0.80, 0.82), (0.84, 0.74, 0.72)],
    "brick": [(0.62, 0.30, 0.22), (0.70, 0.42, 0.30)],
    "concrete": [(0.66, 0.65, 0.62), (0.72, 0.70, 0.66)],
    "ceiling": [(0.93, 0.93, 0.91)],
    "parquet": [(0.55, 0.38, 0.22), (0.62, 0.45, 0.28), (0.45, 0.30, 0.18)],
    "tiles": [(0.50, 0.50, 0.52), (0.42, 0.38, 0.34), (0.58, 0.52, 0.44)],
    "carpet": [(0.35, 0.38, 0.45), (0.45, 0.33, 0.30), (0.36, 0.42, 0.34)],
    "wood": [(0.70, 0.52, 0.32), (0.76, 0.58, 0.38)],
    "dark_wood": [(0.38, 0.24, 0.14), (0.30, 0.20, 0.12)],
    "painted": [(0.20, 0.38, 0.62), (0.70, 0.22, 0.20), (0.25, 0.55, 0.35), (0.85, 0.70, 0.25),
                (0.30, 0.30, 0.32)],
    "fabric": [(0.25, 0.35, 0.60), (0.55, 0.20, 0.25), (0.30, 0.50, 0.40), (0.60, 0.55, 0.45)],
    "marble": [(0.88, 0.88, 0.86), (0.80, 0.80, 0.82)],
    "metal": [(0.55, 0.57, 0.60), (0.40, 0.42, 0.45)],
}


def value_noise(h: int, w: int, cell_px: float, rng: np.random.Generator,
                aspect: float = 1.0) -> np.ndarray:
    """Smooth random field (h, w) in about [0, 1] with features of ``cell_px`` texels.

    ``aspect`` > 1 stretches features along the rows (x), for grain and brushed metal.
    """
    cell_px = max(float(cell_px), 1.0)
    gh = int(np.ceil(h / cell_px)) + 3
    gw = int(np.ceil(w / (cell_px * aspect))) + 3
    grid = rng.random((gh, gw)).astype(np.float32)
    big = cv2.resize(grid, (int(round(gw * cell_px * aspect)), int(round(gh * cell_px))),
                     interpolation=cv2.INTER_CUBIC)
    oy = int(rng.integers(0, max(1, big.shape[0] - h)))
    ox = int(rng.integers(0, max(1, big.shape[1] - w)))
    out = big[oy:oy + h, ox:ox + w]
    if out.shape != (h, w):  # rounding: pad by edge values
        out = np.pad(out, ((0, h - out.shape[0]), (0, w - out.shape[1])), mode="edge")
    return out


def fbm(h: int, w: int, cell_px: float, rng: np.random.Generator, octaves: int = 5,
        persistence: float = 0.55, aspect: float = 1.0) -> np.ndarray:
    """Fractal noise (h, w), zero mean, roughly unit range; the coarsest cell is ``cell_px``."""
    total = np.zeros((h, w), dtype=np.float32)
    amp, norm = 1.0, 0.0
    cell = float(cell_px)
    for _ in range(octaves):
        if cell < 1.5:
            break
        total += amp * (value_noise(h, w, cell, rng, aspect) - 0.5)
        norm += amp
        amp *= persistence
        cell /= 2.0
    return total / max(norm, 1e-6) * 2.0


def spots(h: int, w: int, cell_px: float, rng: np.random.Generator, density: float = 0.12) -> np.ndarray:
    """Sparse blobs (h, w) in [0, 1]: about ``density`` of the area covered."""
    n = value_noise(h, w, cell_px, rng)
    thr = 1.0 - density
    return np.clip((n - thr) / max(density, 1e-3) * 2.0, 0.0, 1.0)


def pick_base(material: str, rng: np.random.Generator) -> np.ndarray:
    """A base color (3,) in [0, 1] for ``material``: one palette entry, slightly jittered."""
    pal = PALETTES[material]
    base = np.asarray(pal[int(rng.integers(len(pal)))], dtype=np.float32)
    return np.clip(base * (1.0 + rng.uniform(-0.04, 0.04, 3).astype(np.float32)), 0, 1)


def _px(metres: float, texel_m: float) -> float:
    return metres / texel_m


def _grain(h: int, w: int, texel_m: float, rng: np.random.Generator, ring_m: float = 0.012) -> np.ndarray:
    """Wood grain along the rows (x): distorted stripes in [0, 1]."""
    y = np.arange(h, dtype=np.float32)[:, None]
    warp = fbm(h, w, _px(0.3, texel_m), rng, octaves=3, aspect=4.0) * _px(0.05, texel_m)
    phase = (y + warp) / _px(ring_m, texel_m) * 2 * np.pi
    stripes = 0.5 + 0.5 * np.sin(phase)
    return stripes ** 3


def material_texture(material: str, h: int, w: int, texel_m: float, rng: np.random.Generator,
                     tone: float = 1.0, base: np.ndarray | None = None) -> np.ndarray:
    """Texture (h, w, 3) uint8 of ``material`` (a name from :data:`PALETTES`) at ``texel_m`` m/texel.

    ``base`` fixes the base color (else one is picked from the palette); ``tone`` scales it.
    """
    h, w = max(int(h), 1), max(int(w), 1)
    base = np.clip((pick_base(material, rng) if base is None else np.asarray(base, np.float32)) * tone, 0, 1)
    px = lambda m: _px(m, texel_m)  # noqa: E731
    y = np.arange(h, dtype=np.float32)[:, None]
    x = np.arange(w, dtype=np.float32)[None, :]
    shade = np.ones((h, w), dtype=np.float32)
    tint = np.zeros((h, w, 3), dtype=np.float32)
    if material in ("plaster", "ceiling", "concrete"):
        amp = {"plaster": 0.10, "ceiling": 0.06, "concrete": 0.16}[material]
        shade += amp * fbm(h, w, px(0.8), rng, octaves=6)
        shade -= (0.25 if material == "concrete" else 0.14) * spots(h, w, px(0.04), rng, 0.10)
        shade += 0.08 * spots(h, w, px(0.06), rng, 0.06)
    elif material == "wallpaper":
        period = px(rng.uniform(0.12, 0.2))
        motif = np.sin(x / period * 2 * np.pi) * np.sin(y / period * 2 * np.pi)
        shade += 0.10 * (np.abs(motif) > 0.6) - 0.06 * (np.abs(np.sin(x / period * np.pi)) < 0.08)
        shade += 0.08 * fbm(h, w, px(0.6), rng)
        shade -= 0.1 * spots(h, w, px(0.05), rng, 0.05)
    elif material == "brick":
        bh, bw, mortar = px(0.075), px(0.23), px(0.012)
        row = np.floor(y / bh)
        xs = x + (row % 2) * bw / 2
        col = np.floor(xs / bw)
        ids = (row * 1000 + col).astype(np.int64)
        per = _hash01(ids, int(rng.integers(1 << 30)))
        is_mortar = ((y % bh) < mortar) | ((xs % bw) < mortar)
        shade = 0.8 + 0.35 * per + 0.15 * fbm(h, w, px(0.3), rng)
        shade = np.where(is_mortar, 1.35 + 0.1 * fbm(h, w, px(0.05), rng), shade)
    elif material in ("parquet", "wood", "dark_wood"):
        plank_w = px(rng.uniform(0.09, 0.15)) if material == "parquet" else px(0.6)
        plank_l = px(rng.uniform(0.6, 1.2)) if material == "parquet" else px(3.0)
        row = np.floor(y / plank_w)
        off = _hash01(row.astype(np.int64), 7) * plank_l
        col = np.floor((x + off) / plank_l)
        ids = (row * 997 + col).astype(np.int64)
        per = _hash01(ids, int(rng.integers(1 << 30)))
        grain = _grain(h, w, texel_m, rng, ring_m=rng.uniform(0.008, 0.02))
        shade = 0.82 + 0.3 * per - 0.22 * grain + 0.08 * fbm(h, w, px(0.5), rng, aspect=3.0)
        if material == "parquet":
            # Subtle seams: real parquet joints are faint; dark seams every plank would flood
            # the panorama with long texture lines that no 3D scan contains.
            seam = ((y % plank_w) < 1.0) | (((x + off) % plank_l) < 1.0)
            shade = np.where(seam, shade * 0.9, shade)
        shade -= 0.2 * spots(h, w, px(0.03), rng, 0.04)  # knots
    elif material == "tiles":
        size = px(rng.choice([0.3, 0.4, 0.5]))
        grout = max(px(0.006), 1.0)
        ids = (np.floor(y / size) * 1000 + np.floor(x / size)).astype(np.int64)
        per = _hash01(ids, int(rng.integers(1 << 30)))
        veins = np.abs(np.sin((x + y) / px(0.2) + 4.0 * fbm(h, w, px(0.3), rng)))
        shade = 0.85 + 0.25 * per + 0.12 * fbm(h, w, px(0.15), rng) - 0.25 * (veins < 0.08)
        shade = np.where(((y % size) < grout) | ((x % size) < grout), shade * 1.1, shade)
    elif material == "carpet":
        shade += 0.22 * fbm(h, w, px(0.25), rng, octaves=6)
        tint += 0.12 * fbm(h, w, px(0.5), rng)[..., None] * np.array([1.0, -0.5, 0.3], np.float32)
        shade -= 0.25 * spots(h, w, px(0.03), rng, 0.08)
    elif material == "painted":
        shade += 0.07 * fbm(h, w, px(0.4), rng) - 0.3 * spots(h, w, px(0.025), rng, 0.05)
        shade += 0.25 * spots(h, w, px(0.05), rng, 0.04)
    elif material == "fabric":
        period = px(0.006) * 2
        weave = np.sin(x / period * np.pi) * np.sin(y / period * np.pi)
        shade += 0.08 * weave + 0.18 * fbm(h, w, px(0.3), rng)
        pattern = (np.sin(x / px(0.1) * np.pi) > 0.7) | (np.sin(y / px(0.1) * np.pi) > 0.7)
        shade += 0.15 * pattern - 0.2 * spots(h, w, px(0.04), rng, 0.05)
    elif material == "marble":
        turb = np.abs(fbm(h, w, px(0.4), rng, octaves=6))
        veins = np.abs(np.sin((x * 0.7 + y) / px(0.25) + 6.0 * turb))
        shade = 1.0 - 0.45 * np.exp(-veins / 0.08) + 0.05 * fbm(h, w, px(0.2), rng)
    elif material == "metal":
        shade += 0.12 * fbm(h, w, px(0.2), rng, aspect=8.0) + 0.05 * fbm(h, w, px(0.8), rng)
        shade -= 0.25 * spots(h, w, px(0.02), rng, 0.05)
    else:
        raise ValueError(f"unknown material {material!r}")
    img = base[None, None, :] * shade[..., None] + tint
    return (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def door_texture(h: int, w: int, texel_m: float, rng: np.random.Generator) -> np.ndarray:
    """A wooden door leaf with inset panels and a dark handle."""
    img = material_texture("wood", h, w, texel_m, rng, tone=rng.uniform(0.75, 1.05)).astype(np.float32)
    y = np.arange(h)[:, None] / max(h, 1)
    x = np.arange(w)[None, :] / max(w, 1)
    inset = ((np.abs(x - 0.5) < 0.36) & (((y > 0.06) & (y < 0.42)) | ((y > 0.5) & (y < 0.94))))
    border = inset & ~(((np.abs(x - 0.5) < 0.33) & (((y > 0.08) & (y < 0.40)) | ((y > 0.52) & (y < 0.92)))))
    img *= np.where(border, 0.6, 1.0)[..., None]
    handle = (np.abs(x - 0.86) < 0.04) & (np.abs(y - 0.52) < 0.02)
    img[handle] = (40, 40, 45)
    return np.clip(img, 0, 255).astype(np.uint8)


def window_texture(h: int, w: int, texel_m: float, rng: np.random.Generator) -> np.ndarray:
    """The view through a window: sky with clouds over a skyline, with a window cross."""
    y = np.arange(h, dtype=np.float32)[:, None] / max(h, 1)
    x = np.arange(w, dtype=np.float32)[None, :] / max(w, 1)
    sky = np.array([0.55, 0.72, 0.92], np.float32)[None, None] * (0.85 + 0.25 * y[..., None])
    clouds = np.clip(fbm(h, w, _px(0.5, texel_m), rng, octaves=6) * 1.5 + 0.2, 0, 1)
    img = sky * (1 - clouds[..., None]) + clouds[..., None] * 0.97
    # Skyline: building heights per column block, with lit windows.
    cols = np.floor(x * rng.uniform(4, 9)).astype(np.int64)
    heights = 0.45 + 0.4 * _hash01(cols, int(rng.integers(1 << 30)))
    building = y > (1 - heights)
    lit = (np.sin(x * w / _px(0.06, texel_m) * np.pi) > 0.3) & (np.sin(y * h / _px(0.08, texel_m) * np.pi) > 0.2)
    bcol = 0.35 + 0.25 * _hash01(cols, 3)[..., None] * np.array([1.0, 0.9, 0.8], np.float32)
    bimg = np.broadcast_to(bcol, img.shape) * np.where(lit, 1.6, 1.0)[..., None]
    img = np.where(building[..., None], bimg, img)
    cross = (np.abs(x - 0.5) * w < _px(0.025, texel_m)) | (np.abs(y - 0.45) * h < _px(0.025, texel_m))
    img = np.where(cross[..., None], 0.92, img)
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def poster_texture(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """A random poster: colored background, shapes and text-like strokes."""
    y = np.arange(h, dtype=np.float32)[:, None]
    x = np.arange(w, dtype=np.float32)[None, :]
    bg = rng.uniform(0.2, 0.95, 3).astype(np.float32)
    img = np.broadcast_to(bg, (h, w, 3)).copy()
    img *= (1 + 0.15 * fbm(h, w, max(h, w) / 2, rng))[..., None]
    s = float(min(h, w))
    for _ in range(int(rng.integers(4, 9))):  # discs and rectangles
        col = rng.uniform(0, 1, 3).astype(np.float32)
        cy, cx = rng.uniform(0, h), rng.uniform(0, w)
        r = rng.uniform(0.06, 0.3) * s
        if rng.random() < 0.5:
            mask = (y - cy) ** 2 + (x - cx) ** 2 < r * r
        else:
            mask = (np.abs(y - cy) < r * rng.uniform(0.3, 1)) & (np.abs(x - cx) < r)
        img[mask] = col
    # Text lines: rows of short dark strokes of random length.
    lh = max(s * rng.uniform(0.035, 0.06), 3.0)
    rows = int(rng.integers(3, 8))
    y0 = rng.uniform(0.55, 0.7) * h
    ink = np.array([0.05, 0.05, 0.08], np.float32) if bg.mean() > 0.5 else np.array([0.97, 0.97, 0.95], np.float32)
    line = np.floor((y - y0) / (1.8 * lh))
    in_line = (line >= 0) & (line < rows) & (((y - y0) % (1.8 * lh)) < lh) & (x > 0.08 * w) & (x < 0.92 * w)
    word = _hash01((line * 1000 + np.floor(x / (lh * 0.7))).astype(np.int64), int(rng.integers(1 << 30)))
    glyph = _hash01((line * 100000 + np.floor(x / (lh * 0.35))).astype(np.int64) * 7 +
                    np.floor(((y - y0) % (1.8 * lh)) / (lh / 3)).astype(np.int64), 11)
    text = in_line & (word > 0.2) & (glyph > 0.35)
    img[text] = ink
    title = (y > 0.08 * h) & (y < 0.08 * h + 2.2 * lh) & (x > 0.1 * w) & (x < rng.uniform(0.5, 0.9) * w)
    img[title & (glyph > 0.45)] = ink
    border = (y < 0.02 * s) | (y > h - 1 - 0.02 * s) | (x < 0.02 * s) | (x > w - 1 - 0.02 * s)
    img[border] = 0.97
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def _hash01(ids: np.ndarray, seed: int) -> np.ndarray:
    """Deterministic pseudo-random value in [0, 1) per integer id (vectorized integer hash)."""
    v = (np.asarray(ids, dtype=np.int64).astype(np.uint64) + np.uint64(seed & 0xFFFFFFFF) * np.uint64(0x9E3779B1))
    v = (v ^ (v >> np.uint64(16))) * np.uint64(0x45D9F3B)
    v = (v ^ (v >> np.uint64(16))) * np.uint64(0x45D9F3B)
    v = v ^ (v >> np.uint64(16))
    return ((v & np.uint64(0xFFFFFF)).astype(np.float32) / np.float32(0x1000000))


def pack_rectangles(sizes: np.ndarray, pad: int = 2, max_side: int = 4096) -> tuple[np.ndarray, int, int]:
    """Shelf-pack rectangles ``sizes`` (N, 2) = (h, w) texels: offsets (N, 2) = (row, col), atlas H, W.

    Raises ValueError when the result would exceed ``max_side`` (the caller shrinks the density).
    """
    sizes = np.asarray(sizes, dtype=np.int64)
    padded = sizes + 2 * pad
    area = int(np.sum(padded[:, 0] * padded[:, 1]))
    width = int(max(np.max(padded[:, 1]), 2 ** int(np.ceil(np.log2(max(np.sqrt(area * 1.15), 16))))))
    if width > max_side:
        raise ValueError("atlas too large")
    order = np.argsort(-padded[:, 0], kind="stable")
    offsets = np.zeros_like(sizes)
    x = y = shelf_h = 0
    for i in order:
        ph, pw = padded[i]
        if x + pw > width:
            y += shelf_h
            x = shelf_h = 0
        offsets[i] = (y + pad, x + pad)
        x += pw
        shelf_h = max(shelf_h, ph)
    height = y + shelf_h
    if height > max_side:
        raise ValueError("atlas too large")
    return offsets, int(height), width
