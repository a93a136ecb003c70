"""Map-building parameters (:func:`ldlmap.map.build.build_map`), one small class per stage, and their checks.

Paper defaults where the paper gives one. The map stores them flat as its config attribute
(:meth:`BuildParams.config`: the keys of :data:`CONFIG_KEYS`, in that order), which stays comparable
across versions: ``ldlmap prepare`` compares it to decide whether a map is up to date. Each check
names the command-line option of its field, so that the CLI reports what the library refuses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

from ldlmap.core.errors import InputError, check_range
from ldlmap.core.frame import parse_up
from ldlmap.features import available_backends
from ldlmap.features.sphere import check_extraction

SCALE_RANGE = (1e-6, 1e6)  # --scale: metres per input unit accepted
MAX_TRANSLATIONS = 20_000  # N_t: the distance fields take ~50 kB per candidate (1 GB at this bound)
MAX_VIEWS = 1000  # views rendered for features (40 by default; each costs a rendering and a feature pass)
MAX_LINE_LENGTH_M = 1000.0  # --min-line-length: longest absolute length threshold accepted
SPACING_RANGE = (1e-3, 1e6)  # --trans-spacing: metres between candidate translations accepted


def check_scale(scale: float) -> None:
    """Refuse a ``scale`` (metres per input unit) outside :data:`SCALE_RANGE` (one line, the CLI's option named)."""
    lo, hi = SCALE_RANGE
    if not (math.isfinite(scale) and lo <= scale <= hi):
        raise InputError(f"--scale must be a number in [{lo:g}, {hi:g}], got {scale:g} (metres per input unit)")


@dataclass(frozen=True)
class InputParams:
    """How the input is read and placed (the ``load`` stage, then scaled and rotated into z-up)."""

    scale: float = 1.0
    """Input coordinates are multiplied by this first (SfM frames: metres per unit; :data:`SCALE_RANGE`)."""
    up: str = "auto"
    """The input's up axis: auto (cameras, else the lines; :mod:`ldlmap.sfm.gravity`) | x | y | z | -x | -y | -z."""
    mesh_samples: int = 1_000_000
    """Points sampled from a mesh input."""
    stations: tuple[str, ...] = ()
    """E57 input: the scan stations to use, names or 0-based indices (all when empty)."""

    def check(self) -> None:
        """Refuse (one line) an up axis or a scale no build can use."""
        parse_up(self.up)
        check_scale(self.scale)


@dataclass(frozen=True)
class LengthFilterParams:
    """The 3D length filter of the ``lines`` stage (paper sec. 3.1), with a floor and a cap on the kept count."""

    lam: float = 0.1
    """lambda: the filter's ratio to the robust extent."""
    min_length: float | None = None
    """Absolute length threshold (m) instead of lambda's: maps of several rooms, whose extent makes lambda's
    threshold longer than most of a room's lines."""
    min_kept: int = 100
    """Floor: keep at least min(this, half the lines), the longest, ..."""
    min_kept_share: float = 0.6
    """... and the longest holding this share of the total line length (below what the paper's threshold keeps
    of a scan, far above an SfM map's: docs/measurements.md#length-share)."""
    max_kept: int = 3000
    """Cap: keep at most this many, the longest."""

    def check(self) -> None:
        """Refuse (one line) a lambda, a length or kept-line bounds no filter can use."""
        check_range(self.lam, "--lambda", 0.0, 1.0)
        if self.min_length is not None and not (math.isfinite(self.min_length)
                                                and 0 < self.min_length <= MAX_LINE_LENGTH_M):
            raise InputError(f"--min-line-length must be a minimum line length in (0, {MAX_LINE_LENGTH_M:g}] m, "
                             f"got {self.min_length:g}")
        if self.min_kept < 0 or self.max_kept < 1 or not 0 <= self.min_kept_share <= 1:
            raise InputError(f"kept-line bounds must be >= 0, >= 1 and a share in [0, 1], got {self.min_kept}, "
                             f"{self.max_kept}, {self.min_kept_share}")


@dataclass(frozen=True)
class PrincipalParams:
    """The map's frame of principal directions (the ``principal`` stage,
    :func:`ldlmap.lines3d.principal.principal_frame`)."""

    orthonormal: bool = True
    """The nearest Manhattan frame (paper's assumption), ..."""
    atlanta: bool = True
    """... or, when the main horizontals are far from perpendicular, an Atlanta frame (the vertical and those
    two). False: always Manhattan."""
    max_horizontals: int = 4
    """Atlanta frames: at most this many horizontal directions, where the walls run in more than two
    (``FrameParams.max_horizontals``; 2: the vertical and the main two only)."""
    max_inclined: int = 2
    """Sloped ceilings: at most this many inclined directions added to the frame (``FrameParams.max_inclined``;
    0: none)."""


@dataclass(frozen=True)
class CandidateParams:
    """The candidate translations (the ``translations`` stage, :mod:`ldlmap.map.translations`)."""

    num: int = 800
    """N_t: candidate translations of a scan (800 OmniScenes, 1700 Stanford 2D-3D-S)."""
    method: str = "octree"
    """How a scan's candidates are placed: octree (OmniScenes) | grid (Stanford)."""
    clearance: float = 0.25
    """Candidate translations keep this distance (m) from the scan."""
    spacing: float = 0.3
    """Maps without a scan (layouts, line files): candidates on a lattice this many metres apart
    (a true camera is then within spacing / sqrt(2) in xy)."""
    camera_height: tuple[float, float] | None = None
    """Camera-height band (metres above each floor the lines show, :mod:`ldlmap.map.floors`) for candidates:
    a scan's N_t go to its free space in the band, a map without a scan gets lattice levels in it. None: the
    layout's known camera heights when it has them, else ``DEFAULT_CAMERA_HEIGHT`` (0.3-2.2 m)."""

    def check(self) -> None:
        """Refuse (one line) a count, a spacing or a camera-height band no build can use."""
        check_range(self.num, "--num-trans", 1, MAX_TRANSLATIONS, integer=True,
                    why="the distance fields take about 50 kB per candidate translation")
        check_range(self.spacing, "--trans-spacing", *SPACING_RANGE, why="input units between candidate translations")
        band = self.camera_height
        if band is None:
            return
        if len(band) != 2:
            raise InputError(f"--camera-height must be MIN:MAX in metres (e.g. 1.2:1.7), got {band}")
        lo, hi = band
        shown = f"{lo:g}:{hi:g}"
        if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
            raise InputError(f"--camera-height must be MIN:MAX with finite MIN <= MAX, got {shown!r}")
        if lo < 0 or hi <= 0:  # heights above the floor (a single height MIN = MAX is a band too)
            raise InputError(f"--camera-height must be heights above the floor, 0 <= MIN <= MAX and MAX > 0 (metres), "
                             f"got {shown!r}")


@dataclass(frozen=True)
class FeatureParams:
    """The map's local features (the ``features`` stage, :mod:`ldlmap.features`)."""

    backend: str = "sift"
    """sift | aliked | disk | xfeat | superpoint | none."""
    weights: str | None = None
    """SuperPoint checkpoint path (else env var / cache / download)."""
    num_views: int = 40
    """Views rendered for features; each translation uses its nearest view."""
    width: int = 1024
    """Rendered view width (the queries' size)."""
    height: int = 512
    """Rendered view height."""
    max_keypoints: int | None = None
    """Keypoints per rendered view (None: the backend's max_keypoints)."""
    extraction: str | None = None
    """equirect (the panorama) | cube (its six 90-degree faces; :mod:`ldlmap.features.sphere`), for the map's
    views and, as the map records it, the queries; None: the backend's default (``default_extraction``)."""

    def check(self) -> None:
        """Refuse (one line) an unknown backend or extraction, or a view count out of bounds."""
        if self.backend not in (*available_backends(), "none"):
            valid = ", ".join(available_backends())
            raise InputError(f"unknown feature backend {self.backend!r}; valid: {valid}, none")
        if self.extraction is not None:
            check_extraction(self.extraction)
        check_range(self.num_views, "--num-views", 1, MAX_VIEWS, integer=True)


@dataclass(frozen=True)
class OutputParams:
    """What the map stores besides its lines and translations."""

    distance_fields: bool = True
    """Precompute 3D distance fields (the ``fields`` stage: fast pose search, :mod:`ldlmap.map.fields3d`)."""
    cloud_points: int = 200_000
    """Subsampled colored cloud kept in the map for pictures."""


@dataclass(frozen=True)
class BuildParams:
    """Parameters of :func:`ldlmap.map.build.build_map`, one group per stage in the order they run."""

    input: InputParams = field(default_factory=InputParams)
    """Reading and placing the input."""
    lines: LengthFilterParams = field(default_factory=LengthFilterParams)
    """The length filter."""
    principal: PrincipalParams = field(default_factory=PrincipalParams)
    """The frame of principal directions."""
    translations: CandidateParams = field(default_factory=CandidateParams)
    """The candidate translations."""
    features: FeatureParams = field(default_factory=FeatureParams)
    """The local features."""
    output: OutputParams = field(default_factory=OutputParams)
    """Distance fields and the stored cloud."""
    device: str = "cpu"
    """Torch device for rendering, distance fields and SuperPoint."""
    seed: int = 0
    """Seed of the view sampling and the stored cloud's subsample."""

    def check(self) -> None:
        """Refuse (one line, naming the CLI option) parameters no build can use, before any work."""
        self.input.check()
        self.lines.check()
        self.translations.check()
        self.features.check()

    def config(self) -> dict[str, Any]:
        """The parameters as the map's config stores them: flat, keyed and ordered by :data:`CONFIG_KEYS`."""
        return {key: getattr(self if group is None else getattr(self, group), name)
                for key, (group, name) in CONFIG_KEYS.items()}

    def replaced(self, **changes: Any) -> BuildParams:
        """A copy with ``changes`` applied, each named by its config key (``features="none"``, ``scale=0.001``)."""
        unknown = sorted(set(changes) - set(CONFIG_KEYS))
        if unknown:
            raise TypeError(f"not a BuildParams config key: {', '.join(unknown)}")
        top, groups = {}, {}
        for key, value in changes.items():
            group, name = CONFIG_KEYS[key]
            (top if group is None else groups.setdefault(group, {}))[name] = value
        top.update({g: replace(getattr(self, g), **kw) for g, kw in groups.items()})
        return replace(self, **top)


# Config key -> (group of BuildParams, None for its own fields; field). The order is the map file's:
# maps written before the groups existed store these keys in this order.
CONFIG_KEYS: dict[str, tuple[str | None, str]] = {
    "lam": ("lines", "lam"),
    "min_line_length": ("lines", "min_length"),
    "num_translations": ("translations", "num"),
    "translation_method": ("translations", "method"),
    "clearance": ("translations", "clearance"),
    "features": ("features", "backend"),
    "weights": ("features", "weights"),
    "num_views": ("features", "num_views"),
    "width": ("features", "width"),
    "height": ("features", "height"),
    "max_keypoints": ("features", "max_keypoints"),
    "feature_extraction": ("features", "extraction"),
    "stored_cloud_points": ("output", "cloud_points"),
    "mesh_samples": ("input", "mesh_samples"),
    "device": (None, "device"),
    "seed": (None, "seed"),
    "distance_fields": ("output", "distance_fields"),
    "trans_spacing": ("translations", "spacing"),
    "camera_height": ("translations", "camera_height"),
    "up": ("input", "up"),
    "scale": ("input", "scale"),
    "min_kept_lines": ("lines", "min_kept"),
    "min_kept_length_share": ("lines", "min_kept_share"),
    "max_kept_lines": ("lines", "max_kept"),
    "orthonormal_directions": ("principal", "orthonormal"),
    "atlanta_frame": ("principal", "atlanta"),
    "max_horizontals": ("principal", "max_horizontals"),
    "max_inclined": ("principal", "max_inclined"),
    "stations": ("input", "stations"),
}


def params_with(params: BuildParams, **changes: Any) -> BuildParams:
    """A copy of ``params`` with the non-None ``changes`` (config keys) applied (for CLI options)."""
    return params.replaced(**{k: v for k, v in changes.items() if v is not None})
