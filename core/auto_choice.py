"""``auto``: per light, the cheapest method whose measured error meets the
scene's error budget.

The measurements are the accuracy study's (``bench/study.py``): every method
at its defaults (256 light samples), its pass filtered like the render, on
the sample scenes against the compositing truth, Cycles' shadow ratio at
1024 samples with the scene's pixel filter; a row per scene holds each
pass's time, its RMSE over the pixels the light reaches and over the
silhouette pixels. The study writes ``bench/results/auto_table.json``; a full
run (``make bench``) installs it as ``core/auto_table.json``, which ships in
the extension (``python -m penumbra.bench.study install-table`` copies a
chosen one).

Parameters: ``budget`` (RMSE over the pixels the light reaches, default
``DEFAULT_BUDGET`` 0.02, the scene's Error Budget; over the silhouette
pixels the allowance is ``SILHOUETTE_ALLOWANCE`` (2) times it), ``visibility`` (the frame's definition of V: ``irradiance``,
the default, or ``average``), the table, and the scene at hand
(``SceneShape``) when there is one.

The rules, in order (each decision says which one in its reason):

1. A light of size zero casts a hard shadow, the same in both definitions:
   ``pcf``, whose size-zero path is the plain shadow-map test (unless
   something moves over the shutter: its shadow is no longer hard).
2. No readable table: the documented fallback ``FALLBACK`` (``pcf``).
3. Scene matching: the table's scenes lit by the same kind of light (area,
   sphere, sun); when none is, every measured scene. With the scene at hand,
   of those the ones that, like it, have (or have not) shadow-casting alpha
   mattes, when the table has any. A method counts with its *worst* error
   over the matched scenes, ``max(RMSE, silhouette RMSE / 2)`` (so "meets
   the budget" means both RMSEs do), and its mean time; a method not
   measured (or failed) on one of them is not a candidate.
4. Candidates are the registered passes measured in the definition needed,
   less the references (``embree``, ``embree_irr``): ``auto`` picks which
   paper's method stands in for the reference.
5. The scene at hand (shadow-casting triangles, output pixels, light size
   relative to its distance from the casters): each candidate's and the
   reference's measured time is scaled to it by ``COST_MODEL``. A candidate
   predicted slower than the reference there is dropped; when every one is,
   ``auto`` runs the reference itself (rule "reference is fastest"). Without
   a shape, times are not scaled. On a scene kept as instances the
   triangles are the instanced ones (every placed triangle) for the methods
   that run on instances (``Method.runs_on_instances``: pcf, and embree for
   the reference: a two-level BVH's depth grows with the log of instances
   times triangles per mesh), and for the others the triangles they expand
   (``SceneShape.expanded``: those of the instances that can shadow a
   visible receiver, when known). When what those would expand cannot fit
   in memory (``SceneShape.instanced_only``), only the methods that run on
   instances are candidates. When something moves over the shutter
   (``SceneShape.moving``), ``auto`` runs the reference, the one method that
   finds occluders at each receiver's time (``Method.shutter_time``; rule
   "moving").
6. The cheapest candidate with worst error <= budget wins; when none meets
   the budget: with a shape, the reference if its own worst error meets it,
   else the most accurate one (the reference too, with a shape), and the
   reason says so.
"""
from __future__ import annotations

import functools
import json
import math
import os
from dataclasses import asdict, dataclass, field
from typing import Dict, List, Mapping, Optional, Sequence

from .scene import LIGHT_KINDS

AVERAGE, IRRADIANCE = "average", "irradiance"
#: RMSE against the compositing truth over the pixels the light reaches: about
#: the noise of Cycles' own shadow pair at 256 samples on the sample scenes
#: (``bench/results/study.md``)
DEFAULT_BUDGET = 0.02
#: over the silhouette pixels (an edge in the filter's footprint) a method may
#: miss by this many times the budget
SILHOUETTE_ALLOWANCE = 2.0
#: without a table: the fast depth-map method, in either definition
FALLBACK = {AVERAGE: "pcf", IRRADIANCE: "pcf"}
#: a light of size zero: the plain shadow-map test (pcf's size-zero path;
#: a hard shadow's V is 0 or 1, the same in both definitions)
HARD = {AVERAGE: "pcf", IRRADIANCE: "pcf"}
#: never candidates: what the picked method's error is measured against
REFERENCES = ("embree", "embree_irr")
TABLE_FORMAT = "penumbra-auto-table/1"
TABLE_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "auto_table.json")


class TableError(ValueError):
    """The table is missing, unreadable or not in TABLE_FORMAT (one line)."""


@dataclass
class MeasuredScene:
    scene: str
    size: str                    # "WxH" of the measurement
    light_kind: str
    light_extent: float
    methods: Dict[str, dict]     # pass id -> {"seconds", "rmse", "visibility", "setting", ...}
    triangles: Optional[int] = None          # shadow-casting triangles (SceneShape)
    light_relative: Optional[float] = None   # light extent / its distance to the casters
    mattes: Optional[int] = None             # shadow-casting triangles with an alpha matte

    @property
    def pixels(self) -> int:
        w, h = (int(x) for x in self.size.lower().split("x"))
        return w * h


@dataclass
class SceneShape:
    """What the scene at hand is, for the cost model (rule 5)."""
    triangles: int               # shadow-casting triangles
    pixels: int                  # output pixels
    light_relative: float        # light extent / distance from the light to the casters' centre
    mattes: int = 0              # shadow-casting triangles with an alpha matte
    #: kept as instances, and what the methods that need world-space
    #: triangles expand would not fit in memory: only the methods that run on
    #: instances (``Method.runs_on_instances``) can run
    instanced_only: bool = False
    #: instances of a scene kept as instances (0: a flattened scene)
    instances: int = 0
    #: kept as instances: the shadow-casting triangles a method that needs
    #: world-space triangles expands (None: all of ``triangles``)
    expanded: Optional[int] = None
    #: objects or the camera move over the shutter (``Scene.motion``)
    moving: bool = False

    def triangles_for(self, mid: str) -> int:
        """The triangles method ``mid``'s time grows with: ``expanded`` for
        a method that needs world-space triangles, else ``triangles``."""
        if self.expanded is None or not self.instances:
            return self.triangles
        from . import methods as registry
        try:
            on_instances = registry.producer_of(mid).runs_on_instances
        except KeyError:
            return self.triangles
        return self.triangles if on_instances else self.expanded

    def describe(self) -> str:
        placed = f" as {self.instances:,} instances" if self.instances else ""
        if self.expanded is not None and self.instances:
            placed += f" ({self.expanded:,} expanded for world-space triangles)"
        return (f"{self.triangles:,} triangles{placed}"
                + (f" ({self.mattes:,} alpha-matted)" if self.mattes else "")
                + (" too large to flatten" if self.instanced_only else "")
                + (", moving over the shutter" if self.moving else "")
                + f", {self.pixels / 1e6:.2f} Mpx, light {self.light_relative:.2f} of its distance")


def scene_shape(scene, light, expanded: Optional[int] = None) -> SceneShape:
    """``SceneShape`` of a captured ``core.scene.Scene`` for one of its
    lights; ``expanded``: on a scene kept as instances, the shadow-casting
    triangles the methods that need world-space triangles expand (None: all)."""
    import numpy as np
    W, H = scene.resolution
    instanced_only, instances = False, 0
    if scene.is_flattened:
        casts = scene.triangles[scene.tri_casts_shadow]
        count = len(casts)
        box = (casts.reshape(-1, 3).min(0), casts.reshape(-1, 3).max(0)) if count else None
    else:                               # instances: their boxes, their placed triangles
        from .scene import BYTES_PER_FLATTENED_TRIANGLE, physical_memory
        ins = scene.instances
        memory = physical_memory()
        expand = ins.instanced_triangles if expanded is None else expanded
        instanced_only = memory is not None and expand * BYTES_PER_FLATTENED_TRIANGLE > memory
        instances = ins.count
        flags = scene.instance_flag("casts_shadow")
        count = int(ins.instance_triangles()[flags].sum())
        boxes = ins.instance_boxes()[flags]
        box = (boxes[:, 0].min(0), boxes[:, 1].max(0)) if count else None
    rel = float(light.extent)
    if light.kind != "sun" and box is not None:
        c = 0.5 * (box[0] + box[1])
        d = float(np.linalg.norm(np.asarray(light.position, float) - c))
        rel = float(light.extent) / max(d, 1e-30)
    mattes = 0
    if getattr(scene, "alpha", None) is not None:
        mattes = int((scene.alpha.tri_matte[scene.tri_casts_shadow] >= 0).sum())
    motion = getattr(scene, "motion", None)
    return SceneShape(count, int(W * H), rel, mattes, instanced_only, instances,
                      expanded if instances else None, motion is not None and motion.moves)


#: rule 5: per method, how its time grows with the scene: (pixel exponent,
#: triangle model, light exponent). "log": a BVH's depth (time x log T ratio);
#: a number b: time x (T ratio)^b; a pair (b_up, b_down): b_up for a scene with
#: more triangles than the measured one, b_down for fewer; light: time x
#: (relative size ratio)^c.
#: embree and penumbra_casting: fitted to ``bench/scaling.py``'s runs on the
#: dense sample scenes (``bench/results/scaling.md``); penumbra casting's
#: cost is linear in the triangles whose penumbra covers a receiver, so its
#: exponent is taken on the side of picking the reference; its pixel and
#: light exponents follow the paper's table 2. The map methods: one
#: rasterization of the triangles and a per-pixel filter (assumed).
COST_MODEL = {
    "embree": (1.0, "log", 0.0),
    "embree_irr": (1.0, "log", 0.0),
    "penumbra_casting": (0.75, (1.2, 1.0), 1.0),
    "depth_raytrace": (1.0, "log", 0.5),
    "irregular": (1.0, 0.3, 0.5),
    "pcf": (1.0, 0.1, 0.0),
    "single_sample": (1.0, 0.1, 0.0),
    "layered": (1.0, 0.2, 0.0),
}
#: methods missing from COST_MODEL: as a ray tracer
_DEFAULT_COST = (1.0, "log", 0.0)


def budget_error(row: Mapping) -> float:
    """A measured row's error in budget terms: its RMSE over the lit pixels
    or its silhouette RMSE / ``SILHOUETTE_ALLOWANCE``, whichever is larger
    (a row without a silhouette figure: its RMSE)."""
    e = float(row["rmse"])
    sil = row.get("rmse_silhouette")
    return e if sil is None else max(e, float(sil) / SILHOUETTE_ALLOWANCE)


def predicted_seconds(mid: str, row: dict, measured: MeasuredScene, shape: Optional[SceneShape]) -> float:
    """The measured ``row`` of ``mid`` scaled from ``measured`` to ``shape``."""
    t = float(row["seconds"])
    if shape is None or not measured.triangles:
        return t
    a, tri, c = COST_MODEL.get(mid, _DEFAULT_COST)
    t *= (max(1, shape.pixels) / max(1, measured.pixels)) ** a
    triangles = shape.triangles_for(mid)
    ratio = max(1, triangles) / max(1, measured.triangles)
    if tri == "log":
        t *= math.log(max(2, triangles)) / math.log(max(2, measured.triangles))
    elif isinstance(tri, tuple):
        t *= ratio ** (tri[0] if ratio > 1 else tri[1])
    else:
        t *= ratio ** tri
    if measured.light_relative and shape.light_relative > 0:
        t *= (shape.light_relative / measured.light_relative) ** c
    return t


@dataclass
class AutoTable:
    scenes: List[MeasuredScene]
    reference: str = ""
    path: str = ""


@dataclass
class AutoChoice:
    """What ``auto`` resolved to, and why (``reason``: one sentence;
    ``short``: a few words for the UI)."""
    method: str
    reason: str
    short: str
    rule: str                    # "hard" | "fallback" | "meets budget" | "most accurate" | "reference is fastest"
                                 # | "moving"
    budget: float
    visibility: str = AVERAGE
    rmse: Optional[float] = None         # worst measured error (``budget_error``) over the matched scenes
    seconds: Optional[float] = None      # mean measured time over the matched scenes
    scenes: List[str] = field(default_factory=list)

    def to_json(self) -> dict:
        return asdict(self)


# --------------------------------------------------------------------------
# the table
def _number(x, what) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) or x < 0:
        raise TableError(f"{what}: expected a finite number >= 0, got {x!r}")
    return float(x)


def parse_table(data: Mapping, path: str = "") -> AutoTable:
    """An AutoTable from the JSON object ``bench/study.py`` writes."""
    where = path or "auto table"
    if not isinstance(data, Mapping) or data.get("format") != TABLE_FORMAT:
        raise TableError(f"{where}: not a {TABLE_FORMAT} table")
    scenes = []
    for k, s in enumerate(data.get("scenes") or []):
        try:
            kind = s["light_kind"]
            if kind not in LIGHT_KINDS:
                raise TableError(f"{where}: scene {k}: unknown light kind {kind!r}")
            methods = {}
            for mid, m in s["methods"].items():
                vis = m["visibility"]
                if vis not in (AVERAGE, IRRADIANCE):
                    raise TableError(f"{where}: {s['scene']}/{mid}: unknown visibility {vis!r}")
                methods[str(mid)] = dict(m, seconds=_number(m["seconds"], f"{where}: {mid} seconds"),
                                         rmse=_number(m["rmse"], f"{where}: {mid} rmse"))
                if m.get("rmse_silhouette") is not None:
                    methods[str(mid)]["rmse_silhouette"] = _number(m["rmse_silhouette"],
                                                                   f"{where}: {mid} rmse_silhouette")
            tri = s.get("triangles")
            rel = s.get("light_relative")
            mat = s.get("mattes")
            scenes.append(MeasuredScene(str(s["scene"]), str(s["size"]), kind,
                                        _number(s["light_extent"], f"{where}: light_extent"), methods,
                                        None if tri is None else int(_number(tri, f"{where}: triangles")),
                                        None if rel is None else _number(rel, f"{where}: light_relative"),
                                        None if mat is None else int(_number(mat, f"{where}: mattes"))))
        except (KeyError, TypeError, AttributeError) as exc:
            raise TableError(f"{where}: scene {k} is malformed ({type(exc).__name__}: {exc})")
    if not scenes:
        raise TableError(f"{where}: no measured scenes")
    return AutoTable(scenes, str(data.get("reference", "")), path)


def load_table(path: str = TABLE_PATH) -> AutoTable:
    """Read and check a table; TableError (one line) when it cannot be used."""
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except FileNotFoundError:
        raise TableError(f"no accuracy table at {path}")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise TableError(f"cannot read the accuracy table {path}: {exc}")
    return parse_table(data, path)


@functools.lru_cache(maxsize=1)
def _packaged():
    try:
        return load_table(TABLE_PATH), None
    except TableError as exc:
        return None, str(exc)


def packaged_table() -> Optional[AutoTable]:
    """The table shipped in ``core/`` (read once), or None."""
    return _packaged()[0]


# --------------------------------------------------------------------------
# the choice
#: the table shipped in core/ (the default of ``choose``)
PACKAGED = object()


def _fmt_s(seconds: float) -> str:
    return f"{seconds * 1e3:.1f} ms" if seconds < 1.0 else f"{seconds:.2f} s"


def choose(kind: str, size: float, visibility: str = IRRADIANCE, budget: float = DEFAULT_BUDGET,
           table=PACKAGED, known: Optional[Sequence[str]] = None,
           shape: Optional[SceneShape] = None) -> AutoChoice:
    """The pass id ``auto`` runs for a light of ``kind`` ("area" | "sphere" |
    "sun") and ``size`` (``Light.extent``) needing ``visibility``, under an
    RMSE ``budget``. ``table``: an AutoTable, a path, None (no table) or,
    by default, the packaged one. ``known``: the pass ids that can run (the
    registry's, by default); others in the table are ignored. ``shape``:
    the scene at hand (rule 5), or None to use the measured times as they are."""
    if visibility not in (AVERAGE, IRRADIANCE):
        raise ValueError(f"auto: visibility must be {AVERAGE!r} or {IRRADIANCE!r}, not {visibility!r}")
    budget = float(budget)
    if not (math.isfinite(budget) and budget > 0):
        raise ValueError(f"auto: the error budget must be a number > 0, not {budget!r}")
    if not size > 0 and not (shape is not None and shape.moving):
        m = HARD[visibility]
        how = ("one depth comparison per pixel, no filtering" if m == "pcf"
               else "one shadow ray per pixel")
        return AutoChoice(m, f"auto -> {m}: the light has size zero, so its shadow is hard: "
                             f"{how} (no table needed)",
                          f"{m}: size zero, hard shadow", "hard", budget, visibility)
    why_none = None
    if table is PACKAGED:
        table, why_none = _packaged()
    elif isinstance(table, str):
        try:
            table = load_table(table)
        except TableError as exc:
            table, why_none = None, str(exc)
    if table is None:
        m = FALLBACK[visibility]
        return AutoChoice(m, f"auto -> {m}: documented fallback, the accuracy table is not available "
                             f"({why_none or 'none given'})", f"{m}: fallback, no accuracy table",
                          "fallback", budget, visibility)
    from . import methods as registry
    if known is None:
        known = registry.pass_ids(external=False)
    if shape is not None and shape.instanced_only:      # rule 5: only what runs on instances
        known = [p for p in known if registry.producer_of(p).runs_on_instances]
    if shape is not None and shape.moving:              # rule 5: only what takes each receiver's time
        ref = REFERENCES[0] if visibility == AVERAGE else REFERENCES[1]
        return AutoChoice(ref, f"auto -> {ref}: objects or the camera move over the shutter, and only the "
                               f"reference finds the occluders where they are at each receiver's time",
                          f"{ref}: motion blur", "moving", budget, visibility)
    matched = [s for s in table.scenes if s.light_kind == kind]
    scope = how = f"{kind}-light scenes"
    if not matched:
        matched, scope = list(table.scenes), "all scenes"
        how = f"all measured scenes (none has a {kind} light)"
    if shape is not None:
        alike = [s for s in matched if s.mattes is not None and (s.mattes > 0) == (shape.mattes > 0)]
        if alike and len(alike) < len(matched):
            matched = alike
            how += " with alpha mattes" if shape.mattes else " without alpha mattes"
    names = [f"{s.scene} {s.size}" for s in matched]
    stats = {}
    ref = REFERENCES[0] if visibility == AVERAGE else REFERENCES[1]
    ref_rows = [s.methods.get(ref) for s in matched]
    ref_t = None
    if all(r is not None for r in ref_rows):
        ref_t = sum(predicted_seconds(ref, r, s, shape) for r, s in zip(ref_rows, matched)) / len(matched)
    slower = []
    for mid in known:
        if mid in REFERENCES:
            continue
        rows = [s.methods.get(mid) for s in matched]
        if any(r is None or r.get("visibility") != visibility for r in rows):
            continue
        t = sum(predicted_seconds(mid, r, s, shape) for r, s in zip(rows, matched)) / len(rows)
        if shape is not None and ref_t is not None and t > ref_t:
            slower.append(mid)              # rule 5: slower than the reference here
            continue
        stats[mid] = (max(budget_error(r) for r in rows), t)
    where = f"{how}: {', '.join(names)}"
    here = f"; for this scene ({shape.describe()}) " if shape is not None else ""
    if slower:
        here += f"{', '.join(sorted(slower))} predicted slower than {ref}"
        if not stats:
            return AutoChoice(ref, f"auto -> {ref}: the reference is fastest here, every measured method is "
                                   f"predicted slower than its {_fmt_s(ref_t)} on {where}{here}",
                              f"{ref}: reference fastest ({shape.triangles:,} triangles)", "reference is fastest",
                              budget, visibility, 0.0, ref_t, names)
    if not stats:
        m = FALLBACK[visibility]
        return AutoChoice(m, f"auto -> {m}: documented fallback, the table measures no method of "
                             f"{visibility} visibility on {where}", f"{m}: fallback, nothing measured",
                          "fallback", budget, visibility, scenes=names)
    meet = [mid for mid, (e, _t) in stats.items() if e <= budget]
    ref_e = max(budget_error(r) for r in ref_rows) if ref_t is not None else None
    if not meet and shape is not None and ref_e is not None:
        if ref_e <= budget:
            return AutoChoice(ref, f"auto -> {ref}: the reference is fastest here, no method predicted faster "
                                   f"than its {_fmt_s(ref_t)} meets the budget {budget:g} (its own worst error "
                                   f"{ref_e:.3f}) on {where}{here}", f"{ref}: reference fastest within {budget:g}",
                              "reference is fastest", budget, visibility, ref_e, ref_t, names)
        if ref_e < min(e for e, _t in stats.values()):
            return AutoChoice(ref, f"auto -> {ref}: no measured method meets the budget {budget:g}; the reference "
                                   f"(worst error {ref_e:.3f} in {_fmt_s(ref_t)}) is more accurate than every method "
                                   f"predicted faster than it on {where}{here}",
                              f"{ref}: most accurate, error {ref_e:.3f} > {budget:g}",
                              "most accurate", budget, visibility, ref_e, ref_t, names)
    if meet:
        m = min(meet, key=lambda k: (stats[k][1], stats[k][0]))
        e, t = stats[m]
        return AutoChoice(m, f"auto -> {m}: cheapest measured method meeting the budget, worst error "
                             f"{e:.3f} <= {budget:g} in {_fmt_s(t)} on {where}{here}",
                          f"{m}: error {e:.3f} <= {budget:g} ({scope})",
                          "meets budget", budget, visibility, e, t, names)
    m = min(stats, key=lambda k: (stats[k][0], stats[k][1]))
    e, t = stats[m]
    return AutoChoice(m, f"auto -> {m}: no measured method meets the budget {budget:g}; the most "
                         f"accurate one, worst error {e:.3f} in {_fmt_s(t)} on {where}{here}",
                      f"{m}: most accurate, error {e:.3f} > {budget:g}",
                      "most accurate", budget, visibility, e, t, names)


def choose_for_light(light, visibility: str = IRRADIANCE, budget: float = DEFAULT_BUDGET,
                     table=PACKAGED, known: Optional[Sequence[str]] = None, scene=None,
                     expanded: Optional[int] = None) -> AutoChoice:
    """``choose`` for a captured ``core.scene.Light`` (of ``scene``, whose
    shape then scales the measured times: rule 5; ``expanded``:
    ``scene_shape``'s)."""
    shape = scene_shape(scene, light, expanded) if scene is not None else None
    return choose(light.kind, light.extent, visibility, budget, table, known, shape)
