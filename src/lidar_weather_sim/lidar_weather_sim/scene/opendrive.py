"""OpenDRIVE (.xodr, 1.4-1.6) road networks: lane poses and a triangle mesh of the roads.

Own compact reader on :mod:`xml.etree` (PyPI ``pyxodr`` 0.1.3 runs on numpy 2 but
samples the reference line at a fixed step, loops per point in Python for spirals,
ignores road marks and objects and pulls in matplotlib/shapely/rich).

Supported: planView ``line``, ``arc``, ``spiral`` (Fresnel integrals),
``poly3``, ``paramPoly3`` (both ``pRange``; numerically arc-length parametrised);
``elevation``, ``superelevation``, ``laneOffset``; lane sections with ``width``
polynomials; ``roadMark`` (solid/broken/double, explicit ``<type><line>``);
guard rails from ``<object type="barrier" name="guardRail">`` with ``<repeat>``,
``<outline>`` (``cornerRoad``/``cornerLocal``) or a ``length``, and the road-level
``<userData code="guardRail" value="left|right|both"/>`` (rails 0.5 m beyond the
outermost lane border; ``offset`` attribute overrides). Not supported: lane
``border`` polynomials (error), ``shape`` lateral profiles, lane heights,
signals, junction geometry beyond its connecting roads.

Frames and units: map frame = the file's inertial frame (x east / along the first
road, y north, z up; m). ``s`` is arc length along a road's reference line (m),
``t`` the lateral offset, positive to the left of increasing ``s`` (m); angles
are rad, counter-clockwise from +x. Lane ids follow OpenDRIVE: negative = right of
the reference line (driving along +s in right-hand traffic), positive = left.

Why one module of ~830 lines: it is one file format. The parser, the lane-pose evaluation and the mesh
all work on the same private road records (_Road, _Section, _Lane); split, those would become a public API.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numba
import numpy as np
import numpy.polynomial.polynomial as _P
from scipy.special import fresnel

from lidar_weather_sim.scene.mesh import TriangleMesh, box_mesh

MAX_STEP_M = 1.0  # longest sampling step along s
MAX_TURN_RAD = 0.005  # largest heading change per step (finer sampling on curves)
MARK_LIFT_M = 0.002  # lane markings float this far above the road surface
DEFAULT_MARK_WIDTH_M = {"standard": 0.12, "bold": 0.25}
DEFAULT_BROKEN_M = (3.0, 9.0)  # line, gap when the file gives none (German Autobahn: 6, 12)
RAIL_TOP_M, RAIL_BEAM_M, RAIL_DEPTH_M = 0.9, 0.3, 0.05  # W-beam: 0.6-0.9 m above ground, 5 cm deep
POST_SPACING_M, POST_SIZE_M = 2.0, 0.1
EDGE_RAIL_GAP_M = 0.5
_NO_SURFACE = {"none"}
_LANE_TYPE_MATERIAL = {"sidewalk": "concrete", "curb": "concrete", "median": "vegetation"}


class OpenDriveError(ValueError):
    """An .xodr file that cannot be read; the message names the file and the element."""


class _Err(Exception):
    def __init__(self, ctx: str, msg: str) -> None:
        super().__init__(ctx, msg)
        self.ctx, self.msg = ctx, msg


_REQUIRED = object()


def _num(el: ET.Element, name: str, ctx: str, default=_REQUIRED) -> float:
    raw = el.get(name)
    if raw is None:
        if default is _REQUIRED:
            raise _Err(ctx, f"missing attribute '{name}'")
        return default
    try:
        value = float(raw)
    except ValueError:
        raise _Err(ctx, f"attribute '{name}'='{raw}' is not a number") from None
    if not np.isfinite(value):
        raise _Err(ctx, f"attribute '{name}'='{raw}' is not finite")
    return value


class _Cubic:
    """Piecewise cubic a + b ds + c ds^2 + d ds^3 over records starting at s0 (ascending)."""

    def __init__(self, records: list[tuple[float, float, float, float, float]]) -> None:
        rec = np.array(sorted(records, key=lambda r: r[0]) or [(0.0, 0.0, 0.0, 0.0, 0.0)], dtype=np.float64)
        self.s0, self.a, self.b, self.c, self.d = rec.T
        # one record (the common case): its coefficients as floats, no per-call lookup
        self.single = tuple(float(v[0]) for v in rec.T) if len(rec) == 1 else None
        # a constant (a + 0 ds, a not -0): the polynomial is exactly a and its derivative +0 at finite ds
        self.constant = self.single is not None and not any(self.single[2:]) and not np.signbit(self.single[1])

    def __call__(self, s: np.ndarray, deriv: bool = False) -> np.ndarray:
        if self.constant:
            return np.full(np.shape(s), 0.0 if deriv else self.single[1])
        if self.single is not None:  # the same expressions with scalar coefficients
            s0, a, b, c, d = self.single
            ds = s - s0
            if deriv:
                return b + ds * (2 * c + 3 * d * ds)
            return a + ds * (b + ds * (c + ds * d))
        i = np.clip(np.searchsorted(self.s0, s, side="right") - 1, 0, None)
        ds = s - self.s0[i]
        if deriv:
            return self.b[i] + ds * (2 * self.c[i] + 3 * self.d[i] * ds)
        return self.a[i] + ds * (self.b[i] + ds * (self.c[i] + ds * self.d[i]))


def _records(parent: ET.Element, tag: str, ctx: str, s_key: str = "s") -> list[tuple]:
    out = []
    for k, el in enumerate(parent.findall(tag)):
        c = f"{ctx}/{tag}[{k + 1}]"
        out.append(tuple(_num(el, key, c, 0.0 if key == "sOffset" else _REQUIRED) for key in (s_key, *"abcd")))
    return out


# ---------------------------------------------------------------- plan view
@dataclass
class _Geometry:
    """One planView record; ``local(ds)`` gives (u, v, dheading, curvature) in its start frame."""

    s0: float
    x: float
    y: float
    hdg: float
    length: float
    kind: str
    p: dict = field(default_factory=dict)
    table: tuple | None = None  # poly geometries: (parameter grid, cumulative arc length)

    def __post_init__(self) -> None:
        if self.kind in ("poly3", "paramPoly3"):
            self._build_table()

    def _coef(self):
        p = self.p
        if self.kind == "poly3":
            return np.array([0.0, 1.0, 0.0, 0.0]), np.array([p["a"], p["b"], p["c"], p["d"]])
        return (np.array([p["aU"], p["bU"], p["cU"], p["dU"]]), np.array([p["aV"], p["bV"], p["cV"], p["dV"]]))

    def _build_table(self) -> None:
        cu, cv = self._coef()
        n = max(512, int(self.length / 0.1))

        def arc(p_end: float):
            q = np.linspace(0.0, p_end, n)
            speed = np.hypot(*(_P.polyval(q, _P.polyder(c)) for c in (cu, cv)))
            return q, np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(q))])

        if self.kind == "poly3":  # parameter u <= arc length: find u_end with arc(u_end) = length
            q, cum = arc(self.length)
            p_end = float(np.interp(self.length, cum, q))
        else:
            p_end = 1.0 if self.p.get("pRange", "normalized") == "normalized" else self.length
        self.table = arc(p_end)

    def local(self, ds: np.ndarray):
        zero = np.zeros_like(ds)
        if self.kind == "line":
            return ds, zero, zero, zero
        if self.kind == "arc":
            return _arc_local(ds, self.p["curvature"])
        if self.kind == "spiral":
            return _spiral_local(ds, self.p["curvStart"], self.p["curvEnd"], self.length)
        q_grid, cum = self.table
        q = np.interp(ds * cum[-1] / self.length, cum, q_grid)
        cu, cv = self._coef()
        u, v = _P.polyval(q, cu), _P.polyval(q, cv)
        du, dv = _P.polyval(q, _P.polyder(cu)), _P.polyval(q, _P.polyder(cv))
        d2u, d2v = _P.polyval(q, _P.polyder(cu, 2)), _P.polyval(q, _P.polyder(cv, 2))
        k = (du * d2v - dv * d2u) / np.maximum(np.hypot(du, dv), 1e-12) ** 3
        return u, v, np.arctan2(dv, du), k

    @cached_property
    def step(self) -> float:
        """Sampling step (m): MAX_STEP_M, shorter where |curvature| * step would exceed MAX_TURN_RAD."""
        if self.kind == "line":
            kmax = 0.0
        elif self.kind == "arc":
            kmax = abs(self.p["curvature"])
        elif self.kind == "spiral":
            kmax = max(abs(self.p["curvStart"]), abs(self.p["curvEnd"]))
        else:
            kmax = float(np.abs(self.local(np.linspace(0.0, self.length, 256))[3]).max())
        return MAX_STEP_M if kmax * MAX_STEP_M <= MAX_TURN_RAD else MAX_TURN_RAD / kmax


def _arc_local(ds: np.ndarray, k: float):
    if abs(k) < 1e-15:
        return ds, np.zeros_like(ds), np.zeros_like(ds), np.zeros_like(ds)
    th = k * ds
    return np.sin(th) / k, 2.0 * np.sin(0.5 * th) ** 2 / k, th, np.full_like(ds, k)


def _spiral_local(ds: np.ndarray, k0: float, k1: float, length: float):
    """Clothoid with curvature k0 + c ds, c = (k1 - k0) / length, via the Fresnel integrals."""
    c = (k1 - k0) / length
    dh = k0 * ds + 0.5 * c * ds * ds
    if abs(c) * length**3 < 1e-9:  # position error ~ c L^3 / 6
        u, v, _, _ = _arc_local(ds, k0 + 0.5 * c * length)
        return u, v, dh, k0 + c * ds
    a = np.sqrt(np.pi / abs(c))
    t0 = k0 / c  # arc length from the clothoid's inflection point
    S, C = fresnel((t0 + ds) / a)
    S0, C0 = fresnel(t0 / a)
    X, Y = a * (C - C0), np.sign(c) * a * (S - S0)
    th0 = 0.5 * c * t0 * t0
    return X * np.cos(th0) + Y * np.sin(th0), -X * np.sin(th0) + Y * np.cos(th0), dh, k0 + c * ds


class _PlanView:
    def __init__(self, geoms: list[_Geometry]) -> None:
        self.geoms = sorted(geoms, key=lambda g: g.s0)
        self.s0 = np.array([g.s0 for g in self.geoms])
        self._cos_sin = [(np.cos(g.hdg), np.sin(g.hdg)) for g in self.geoms]

    def __call__(self, s: np.ndarray):
        """x, y, heading, curvature of the reference line at ``s`` (arrays like ``s``)."""
        if len(self.geoms) == 1:
            return self._eval(0, s)
        i = np.searchsorted(self.s0, s, side="right") - 1
        lo, hi = (int(i.min()), int(i.max())) if i.size else (0, 0)
        if max(lo, 0) == min(hi, len(self.geoms) - 1):  # all in one geometry: no masks
            return self._eval(max(lo, 0), s)
        i = np.clip(i, 0, len(self.geoms) - 1)
        out = np.empty((4,) + s.shape)
        for gi in np.unique(i):
            m = i == gi
            out[:, m] = self._eval(gi, s[m])
        return out

    def _eval(self, gi: int, s: np.ndarray):
        g, (ch, sh) = self.geoms[gi], self._cos_sin[gi]
        u, v, dh, k = g.local(np.minimum(np.maximum(s - g.s0, 0.0), g.length))
        return g.x + u * ch - v * sh, g.y + u * sh + v * ch, g.hdg + dh, k


# ---------------------------------------------------------------- lanes, marks, rails
@dataclass
class _Mark:
    s0: float  # road s where this record starts (m)
    s1: float
    lines: list[tuple[float, float, float, float, float]]  # (length, space, tOffset, sOffset, width); space 0 = solid


@dataclass
class _Lane:
    id: int
    type: str
    width: _Cubic
    marks: list[_Mark]


@dataclass
class _Section:
    s0: float
    s1: float
    lanes: dict[int, _Lane]


@dataclass
class _Rail:
    """Guard rail: knots (s, t, bottom, top) along the road, a map-frame polyline, or a road edge."""

    name: str
    knots: np.ndarray | None = None  # (k, 4), s ascending
    polyline: np.ndarray | None = None  # (k, 5): x, y, z_ground, bottom, top
    edge_side: int = 0  # +1 left edge, -1 right edge
    edge_gap: float = EDGE_RAIL_GAP_M


@dataclass
class _Road:
    id: str
    name: str
    length: float
    rule: str
    plan: _PlanView
    elevation: _Cubic
    superelevation: _Cubic
    offset: _Cubic
    sections: list[_Section]
    rails: list[_Rail]
    # (section index, lane id) -> its centre t, d t / d s, width where those do not depend on s
    constant_centres: dict = field(default_factory=dict, repr=False)

    def frame(self, s: np.ndarray) -> tuple[np.ndarray, ...]:
        """x, y, heading, curvature, z, superelevation of the reference line (arrays like ``s``)."""
        x, y, h, k = self.plan(s)
        return x, y, h, k, self.elevation(s), self.superelevation(s)

    @staticmethod
    def point(f: tuple[np.ndarray, ...], t: np.ndarray) -> np.ndarray:
        """Map-frame points (..., 3) at lateral offset ``t`` from frame ``f``."""
        return np.stack(_Road.coordinates(f, t), axis=-1)

    @staticmethod
    def coordinates(f: tuple[np.ndarray, ...], t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """x, y, z (m, like ``t``) of :meth:`point`."""
        x, y, h, _, z, phi = f
        lat = t * np.cos(phi)
        return x - lat * np.sin(h), y + lat * np.cos(h), z + t * np.sin(phi)

    def section_index(self, s: np.ndarray) -> np.ndarray:
        s0 = np.array([sec.s0 for sec in self.sections])
        return np.clip(np.searchsorted(s0, s, side="right") - 1, 0, len(s0) - 1)

    def lane_borders(self, sec: _Section, lane_id: int, s: np.ndarray, deriv: bool = False):
        """(outer, inner) border t of lane ``lane_id`` (or d t / d s): ``borders`` summed only
        as far as that lane (the same sums)."""
        sign = 1 if lane_id > 0 else -1
        inner = t = self.offset(s, deriv)
        for k in range(1, abs(lane_id) + 1):
            inner, t = t, t + sign * sec.lanes[sign * k].width(s - sec.s0, deriv)
        return t, inner

    def borders(self, sec: _Section, s: np.ndarray, deriv: bool = False) -> dict[int, np.ndarray]:
        """Lane id -> t of its outer border (0 -> lane offset line), or d t / d s."""
        out = {0: self.offset(s, deriv)}
        for sign in (-1, 1):
            t = out[0]
            for lid in sorted((i for i in sec.lanes if i * sign > 0), key=abs):
                t = t + sign * sec.lanes[lid].width(s - sec.s0, deriv)
                out[lid] = t
        return out


def _parse_geometry(el: ET.Element, ctx: str) -> _Geometry:
    base = {k: _num(el, k, ctx) for k in ("s", "x", "y", "hdg", "length")}
    if base["length"] <= 0:
        raise _Err(ctx, f"attribute 'length'={base['length']} must be > 0")
    kinds = [c for c in el if c.tag in ("line", "arc", "spiral", "poly3", "paramPoly3")]
    if len(kinds) != 1:
        raise _Err(ctx, f"expected one of line/arc/spiral/poly3/paramPoly3, found {[c.tag for c in el] or 'none'}")
    kel = kinds[0]
    kctx = f"{ctx}/{kel.tag}"
    keys = {"line": (), "arc": ("curvature",), "spiral": ("curvStart", "curvEnd"), "poly3": tuple("abcd"),
            "paramPoly3": tuple(f"{c}{a}" for a in "UV" for c in "abcd")}[kel.tag]  # fmt: skip
    p = {k: _num(kel, k, kctx) for k in keys}
    if kel.tag == "paramPoly3":
        p["pRange"] = kel.get("pRange", "normalized")
        if p["pRange"] not in ("normalized", "arcLength"):
            raise _Err(kctx, f"attribute 'pRange'='{p['pRange']}' is not 'normalized' or 'arcLength'")
    return _Geometry(base["s"], base["x"], base["y"], base["hdg"], base["length"], kel.tag, p)


def _parse_marks(lane_el: ET.Element, s0: float, s1: float, ctx: str) -> list[_Mark]:
    raw = []
    for k, m in enumerate(lane_el.findall("roadMark")):
        c = f"{ctx}/roadMark[{k + 1}]"
        off = _num(m, "sOffset", c, 0.0)
        width = _num(m, "width", c, DEFAULT_MARK_WIDTH_M.get(m.get("weight", "standard"), 0.12))
        lines = []
        for j, ln in enumerate(m.findall("type/line")):
            lc = f"{c}/type/line[{j + 1}]"
            lines.append((_num(ln, "length", lc), _num(ln, "space", lc), _num(ln, "tOffset", lc, 0.0),
                          _num(ln, "sOffset", lc, 0.0), _num(ln, "width", lc, width)))  # fmt: skip
        if not lines:
            parts = m.get("type", "none").split()
            if parts and all(p in ("solid", "broken") for p in parts):
                offsets = [0.0] if len(parts) == 1 else [width, -width]  # first word = left (larger t) line
                for p, t_off in zip(parts, offsets):
                    length, space = (1.0, 0.0) if p == "solid" else DEFAULT_BROKEN_M
                    lines.append((length, space, t_off, 0.0, width))
        raw.append((s0 + off, lines))
    ends = [r[0] for r in raw[1:]] + [s1]
    return [_Mark(a, b, lines) for (a, lines), b in zip(raw, ends) if lines and b > a]


def _parse_section(el: ET.Element, s1: float, ctx: str) -> _Section:
    s0 = _num(el, "s", ctx)
    lanes: dict[int, _Lane] = {}
    for side in ("left", "center", "right"):
        for k, ln in enumerate(el.findall(f"{side}/lane")):
            c = f"{ctx}/{side}/lane[{k + 1}]"
            lid = int(_num(ln, "id", c))
            if np.sign(lid) != {"left": 1, "center": 0, "right": -1}[side]:
                raise _Err(c, f"lane id {lid} does not belong in <{side}>")
            widths = _records(ln, "width", c, "sOffset")
            if lid != 0 and not widths:
                hint = " (<border> is not supported, use <width>)" if ln.find("border") is not None else ""
                raise _Err(c, f"lane {lid} has no <width>{hint}")
            lanes[lid] = _Lane(lid, ln.get("type", "driving"), _Cubic(widths), _parse_marks(ln, s0, s1, c))
    for sign in (-1, 1):
        ids = sorted(abs(i) for i in lanes if i * sign > 0)
        if ids != list(range(1, len(ids) + 1)):
            raise _Err(ctx, f"lane ids {[sign * i for i in ids]} are not consecutive from {sign}")
    return _Section(s0, s1, lanes)


def _beam(z_offset: float, height: float | None) -> tuple[float, float]:
    """(bottom, top) of the W-beam above ground: top = zOffset + height, beam <= RAIL_BEAM_M high."""
    if height is None or height <= 0:
        return RAIL_TOP_M - RAIL_BEAM_M, RAIL_TOP_M
    top = z_offset + height
    return max(z_offset, top - RAIL_BEAM_M), top


def _parse_rails(road_el: ET.Element, road: _Road, ctx: str) -> list[_Rail]:
    rails = []
    for k, ud in enumerate(road_el.findall("userData")):
        if ud.get("code", "").lower().replace("_", "") in ("guardrail", "guardrails"):
            value = ud.get("value", "both").lower()
            if value not in ("left", "right", "both"):
                raise _Err(f"{ctx}/userData[{k + 1}]", f"attribute 'value'='{value}' is not left/right/both")
            gap = _num(ud, "offset", f"{ctx}/userData[{k + 1}]", EDGE_RAIL_GAP_M)
            for side, sign in (("left", 1), ("right", -1)):
                if value in (side, "both"):
                    rails.append(_Rail(f"road {road.id} {side} edge guard rail", edge_side=sign, edge_gap=gap))
    for k, obj in enumerate(road_el.findall("objects/object")):
        c = f"{ctx}/objects/object[{k + 1}]"
        tag = (obj.get("name", "") + obj.get("subtype", "")).lower().replace(" ", "").replace("_", "")
        if obj.get("type") not in ("barrier", "railing", None) or "guardrail" not in tag:
            continue
        name = f"road {road.id} guard rail {obj.get('id', k + 1)}"
        s, t, z = _num(obj, "s", c), _num(obj, "t", c), _num(obj, "zOffset", c, 0.0)
        height = _num(obj, "height", c, None)
        n_before = len(rails)
        for j, rep in enumerate(obj.findall("repeat")):
            rc = f"{c}/repeat[{j + 1}]"
            rs, rl = _num(rep, "s", rc), _num(rep, "length", rc)
            ends = []
            for end in ("Start", "End"):
                zo, h = _num(rep, f"zOffset{end}", rc, z), _num(rep, f"height{end}", rc, height)
                ends.append((_num(rep, f"t{end}", rc, t), *_beam(zo, h)))
            rails.append(_Rail(name, knots=np.array([(rs, *ends[0]), (rs + rl, *ends[1])])))
        for j, outline in enumerate(obj.findall("outline") + obj.findall("outlines/outline")):
            oc = f"{c}/outline[{j + 1}]"
            road_c, local_c = outline.findall("cornerRoad"), outline.findall("cornerLocal")
            if road_c:
                kn = []
                for i, cr in enumerate(road_c):
                    cc = f"{oc}/cornerRoad[{i + 1}]"
                    kn.append((_num(cr, "s", cc), _num(cr, "t", cc),
                               *_beam(z + _num(cr, "dz", cc, 0.0), _num(cr, "height", cc, height))))  # fmt: skip
                kn = np.array(kn)
                if len(kn) < 2 or np.any(np.diff(kn[:, 0]) <= 0):
                    raise _Err(oc, "a guard rail outline needs >= 2 cornerRoad points with increasing s")
                rails.append(_Rail(name, knots=kn))
            elif local_c:
                uv = []
                for i, cl in enumerate(local_c):
                    cc = f"{oc}/cornerLocal[{i + 1}]"
                    uv.append((_num(cl, "u", cc), _num(cl, "v", cc),
                               *_beam(z + _num(cl, "z", cc, 0.0), _num(cl, "height", cc, height))))  # fmt: skip
                rails.append(_Rail(name, polyline=_local_polyline(road, obj, c, s, t, np.array(uv))))
        if len(rails) == n_before:
            length = _num(obj, "length", c, 0.0)
            if length <= 0:
                raise _Err(c, "guard rail object has no <repeat>, <outline> or 'length'")
            uv = np.array([(-0.5 * length, 0.0, *_beam(z, height)), (0.5 * length, 0.0, *_beam(z, height))])
            rails.append(_Rail(name, polyline=_local_polyline(road, obj, c, s, t, uv)))
    return rails


def _local_polyline(road: _Road, obj: ET.Element, ctx: str, s: float, t: float, uvbt: np.ndarray) -> np.ndarray:
    """Object-local corners (u, v, bottom, top) -> map-frame (x, y, z_ground, bottom, top)."""
    f = road.frame(np.array(s))
    origin = _Road.point(f, np.array(t))
    hdg = float(f[2]) + _num(obj, "hdg", ctx, 0.0)
    u, v = uvbt[:, 0], uvbt[:, 1]
    x = origin[0] + u * np.cos(hdg) - v * np.sin(hdg)
    y = origin[1] + u * np.sin(hdg) + v * np.cos(hdg)
    return np.column_stack([x, y, np.full_like(x, origin[2]), uvbt[:, 2], uvbt[:, 3]])


def _parse_road(el: ET.Element, k: int) -> _Road:
    rid = el.get("id")
    ctx = f"road[id={rid}]" if rid is not None else f"road[{k + 1}]"
    if rid is None:
        raise _Err(ctx, "missing attribute 'id'")
    length = _num(el, "length", ctx)
    geom_els = el.findall("planView/geometry")
    geoms = [_parse_geometry(g, f"{ctx}/planView/geometry[{j + 1}]") for j, g in enumerate(geom_els)]
    if not geoms:
        raise _Err(f"{ctx}/planView", "no <geometry>")
    sec_els = el.findall("lanes/laneSection")
    if not sec_els:
        raise _Err(f"{ctx}/lanes", "no <laneSection>")
    starts = [_num(s, "s", f"{ctx}/lanes/laneSection[{j + 1}]") for j, s in enumerate(sec_els)]
    if starts != sorted(starts):
        raise _Err(f"{ctx}/lanes", f"laneSection s values {starts} are not ascending")
    sections = [_parse_section(s, e, f"{ctx}/lanes/laneSection[{j + 1}]")
                for j, (s, e) in enumerate(zip(sec_els, starts[1:] + [length]))]  # fmt: skip
    road = _Road(
        rid, el.get("name", ""), length, el.get("rule", "RHT"), _PlanView(geoms),
        _Cubic(_records(el, "elevationProfile/elevation", ctx)),
        _Cubic(_records(el, "lateralProfile/superelevation", ctx)),
        _Cubic(_records(el, "lanes/laneOffset", ctx)), sections, [],
    )  # fmt: skip
    road.rails = _parse_rails(el, road, ctx)
    return road


# ---------------------------------------------------------------- mesh helpers
def _strip(a: np.ndarray, b: np.ndarray, up: np.ndarray | None = None):
    """Quad strips between rows a and b, each (D, n, 3); winding so normals point along ``up``."""
    D, n, _ = a.shape
    if up is not None:
        e1, e2 = np.diff(a, axis=1), (b - a)[:, :-1]
        up = np.asarray(up)
        if np.sum(np.cross(e1, e2) * (up[..., :-1, :] if up.ndim > 1 else up)) < 0:
            a, b = b, a
    V = np.stack([a, b], axis=2).reshape(-1, 3)
    base = 2 * (np.arange(D)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    T = np.concatenate([np.stack([base, base + 2, base + 1], 1), np.stack([base + 1, base + 2, base + 3], 1)])
    return V, T


_UNIT_BOX = box_mesh((1.0, 1.0, 1.0), 0, 0)


def _boxes(bottom_centres: np.ndarray, heading: np.ndarray, size_xy: tuple[float, float], height: np.ndarray):
    """N boxes (size_xy along / across ``heading``, ``height`` (N,)) standing on ``bottom_centres`` (N, 3)."""
    c = _UNIT_BOX.vertices * np.array([size_xy[0], size_xy[1], 1.0])
    ch, sh = np.cos(heading)[:, None], np.sin(heading)[:, None]
    z = c[:, 2] * np.asarray(height)[:, None]
    V = np.stack([c[:, 0] * ch - c[:, 1] * sh, c[:, 0] * sh + c[:, 1] * ch, z], -1) + bottom_centres[:, None, :]
    T = _UNIT_BOX.triangles[None] + 8 * np.arange(len(bottom_centres))[:, None, None]
    return V.reshape(-1, 3), T.reshape(-1, 3)


def _rail_mesh(pts: np.ndarray, bottom: np.ndarray, top: np.ndarray, away: np.ndarray):
    """Closed W-beam tube and posts along ground polyline ``pts`` (n, 3), facing the xy point ``away``."""
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts[:, :2], axis=0), axis=1) > 1e-6])
    pts, bottom, top = pts[keep], bottom[keep], top[keep]
    d = np.gradient(pts[:, :2], axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    left = np.column_stack([-d[:, 1], d[:, 0]])
    mid = len(pts) // 2
    out = left * (1.0 if np.dot(left[mid], pts[mid, :2] - away) >= 0 else -1.0)
    o3 = np.column_stack([out * RAIL_DEPTH_M, np.zeros(len(pts))])
    ib, it = pts.copy(), pts.copy()
    ib[:, 2] += bottom
    it[:, 2] += top
    ob, ot = ib + o3, it + o3
    out3, z = np.c_[out, np.zeros(len(pts))], np.array([0.0, 0.0, 1.0])
    parts = [_strip(ib[None], it[None], -out3), _strip(ob[None], ot[None], out3),
             _strip(it[None], ot[None], z), _strip(ib[None], ob[None], -z)]  # fmt: skip
    for i, sgn in ((0, -1.0), (-1, 1.0)):  # end caps facing backwards / forwards
        parts.append(_strip(np.stack([ib[i], ob[i]])[None], np.stack([it[i], ot[i]])[None], sgn * np.r_[d[i], 0.0]))
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    sp = np.arange(0.5 * POST_SIZE_M, arc[-1] - 0.5 * POST_SIZE_M + 1e-9, POST_SPACING_M)
    if len(sp):
        P = np.column_stack([np.interp(sp, arc, pts[:, j]) for j in range(3)])
        behind = RAIL_DEPTH_M + 0.5 * POST_SIZE_M
        P[:, :2] += np.column_stack([np.interp(sp, arc, out[:, j]) for j in range(2)]) * behind
        hd = np.arctan2(np.interp(sp, arc, d[:, 1]), np.interp(sp, arc, d[:, 0]))
        parts.append(_boxes(P, hd, (POST_SIZE_M, POST_SIZE_M), np.interp(sp, arc, top)))
    return parts


# ---------------------------------------------------------------- public API
class RoadNetwork:
    """Roads of one .xodr file; see the module docstring for frames and units."""

    def __init__(self, roads: dict[str, _Road], source: str = "<memory>") -> None:
        self.roads = roads
        self.source = source

    @classmethod
    def from_xodr(cls, path: str | Path) -> "RoadNetwork":
        """Parse ``path``; :class:`OpenDriveError` names the file and the offending element."""
        path = Path(path)
        try:
            root = ET.parse(path).getroot()
        except OSError as exc:
            raise OpenDriveError(f"{path}: cannot read: {exc.strerror or exc}") from None
        except ET.ParseError as exc:
            line, col = exc.position
            raise OpenDriveError(f"{path}: line {line}, column {col}: not well-formed XML") from None
        try:
            if root.tag != "OpenDRIVE":
                raise _Err(f"<{root.tag}>", "root element is not <OpenDRIVE>")
            roads = [_parse_road(el, k) for k, el in enumerate(root.findall("road"))]
            if not roads:
                raise _Err("OpenDRIVE", "no <road>")
        except _Err as err:
            raise OpenDriveError(f"{path}: element {err.ctx}: {err.msg}") from None
        ids = [r.id for r in roads]
        if len(set(ids)) != len(ids):
            raise OpenDriveError(f"{path}: duplicate road ids in {ids}")
        return cls({r.id: r for r in roads}, str(path))

    @property
    def road_ids(self) -> list[str]:
        return list(self.roads)

    def _road(self, road_id: str) -> _Road:
        try:
            return self.roads[str(road_id)]
        except KeyError:
            raise KeyError(f"{self.source}: no road '{road_id}'; roads: {', '.join(self.roads)}") from None

    def road_length(self, road_id: str) -> float:
        """Length of the road's reference line (m)."""
        return self._road(road_id).length

    def lane_ids(self, road_id: str) -> list[int]:
        """Sorted ids of all non-centre lanes of any lane section of the road."""
        return sorted({i for sec in self._road(road_id).sections for i in sec.lanes if i != 0})

    def _s(self, road: _Road, s) -> np.ndarray:
        s = np.asarray(s, dtype=np.float64)
        if s.size and (s.min() < -1e-6 or s.max() > road.length + 1e-6):
            raise ValueError(f"road '{road.id}': s outside [0, {road.length}] m")
        return np.minimum(np.maximum(s, 0.0), road.length)  # np.clip, without its per-call overhead

    def reference_pose(self, road_id: str, s, t=0.0):
        """(x, y, z, heading) at (s, t) (m); heading of the reference line (rad), like ``s``."""
        road = self._road(road_id)
        s = self._s(road, s)
        f = road.frame(s)
        p = _Road.point(f, np.broadcast_to(np.asarray(t, dtype=np.float64), s.shape))
        return p[..., 0], p[..., 1], p[..., 2], f[2]

    @staticmethod
    def _centre(road: _Road, sec: _Section, lane_id: int, s: np.ndarray):
        """Centre t, d t / d s and width (m) of lane ``lane_id`` of section ``sec`` at ``s``."""
        if lane_id == 0 or lane_id not in sec.lanes:
            raise KeyError(f"road '{road.id}': no lane {lane_id} in the lane section at s={sec.s0} m")
        (b, bi), (db, dbi) = road.lane_borders(sec, lane_id, s), road.lane_borders(sec, lane_id, s, deriv=True)
        return 0.5 * (b + bi), 0.5 * (db + dbi), np.abs(b - bi)

    def _fixed_centre(self, road: _Road, lane_id: int) -> list[float] | None:
        """:meth:`_centre` of a lane whose centre does not depend on s (one lane section, constant
        lane offset and widths): the values at any s (cached); else None."""
        if len(road.sections) != 1:
            return None
        key = (0, lane_id)
        if key not in road.constant_centres:
            sec = road.sections[0]
            fixed = road.offset.constant and all(sec.lanes[k].width.constant for k in sec.lanes if k * lane_id > 0)
            if fixed:
                fixed = [float(v[0]) for v in self._centre(road, sec, lane_id, np.zeros(1))]
            road.constant_centres[key] = fixed or None
        return road.constant_centres[key]

    def _lane_t(self, road: _Road, lane_id: int, s: np.ndarray):
        """Lane centre t, d t / d s and lane width (m) at ``s``."""
        fixed = self._fixed_centre(road, lane_id)
        if fixed is not None:
            return tuple(np.full(s.shape, v) for v in fixed)
        if len(road.sections) == 1:
            return self._centre(road, road.sections[0], lane_id, s)
        t, dt, width = np.empty_like(s), np.empty_like(s), np.empty_like(s)
        isec = road.section_index(s)
        for k in np.unique(isec):
            m = isec == k
            t[m], dt[m], width[m] = self._centre(road, road.sections[k], lane_id, s[m])
        return t, dt, width

    def lane_pose(self, road_id: str, lane_id, s_m, along_reference: bool = False):
        """(x, y, z, heading_rad) of the lane centre at ``s_m`` (m along the reference line).

        Vectorised over ``s_m``; ``lane_id`` is one lane or an int array like ``s_m`` (a lane
        per s: the values of one call per lane). The heading is the lane centre's tangent in
        the lane's driving direction (right lanes along +s, left lanes against it in
        right-hand traffic, the reverse for ``rule="LHT"``) unless ``along_reference``.
        """
        road = self._road(road_id)
        s = self._s(road, s_m)
        lanes = np.asarray(lane_id)
        against = road.rule.upper() != "LHT"  # lanes with id > 0 drive against +s
        if lanes.ndim:
            ids, k = _lane_index(np.ascontiguousarray(lanes, np.int64))
            if len(ids) == 1:  # one lane
                lanes = lane_id = lanes[0]
        if lanes.ndim == 0:
            t, dt, _ = self._lane_t(road, int(lane_id), s)
            flip = (lane_id > 0) == against
        else:
            flip, ids = (lanes > 0) == against, ids.tolist()
            fixed = [self._fixed_centre(road, lane) for lane in ids]
            if None not in fixed:  # centres independent of s: gathered per lane, no masks
                table = np.array(fixed).reshape(-1, 3)
                t, dt = table[k, 0], table[k, 1]
            else:
                t, dt = np.empty_like(s), np.empty_like(s)
                for lane in ids:
                    m = lanes == lane
                    t[m], dt[m], _ = self._lane_t(road, lane, s[m])
        f = road.frame(s)
        x, y, z = _Road.coordinates(f, t)
        heading = f[2] + np.arctan2(dt, 1.0 - f[3] * t)
        if not along_reference and lanes.ndim == 0 and flip:
            heading = heading + np.pi
        elif not along_reference and lanes.ndim and flip.any():
            heading[flip] = heading[flip] + np.pi
        return x, y, z, np.angle(np.exp(1j * heading))

    def lane_width(self, road_id: str, lane_id: int, s_m) -> np.ndarray:
        """Width of the lane at ``s_m`` (m)."""
        road = self._road(road_id)
        return self._lane_t(road, int(lane_id), self._s(road, s_m))[2]

    def sample_s(self, road_id: str) -> np.ndarray:
        """The s grid the mesh uses: <= MAX_STEP_M, finer on curves, all record starts included."""
        road = self._road(road_id)
        bps = [g.s0 for g in road.plan.geoms] + [0.0, road.length]
        for sec in road.sections:
            bps += [sec.s0] + [sec.s0 + w for lane in sec.lanes.values() for w in lane.width.s0]
        for cub in (road.elevation, road.superelevation, road.offset):
            bps += list(cub.s0)
        bps = np.unique(np.clip(bps, 0.0, road.length))
        bps = bps[np.concatenate([[True], np.diff(bps) > 1e-6])]
        bps[-1] = road.length
        steps = [g.step for g in road.plan.geoms]
        pieces = []
        for a, b in zip(bps[:-1], bps[1:]):
            gi = np.clip(np.searchsorted(road.plan.s0, 0.5 * (a + b), side="right") - 1, 0, len(steps) - 1)
            n = max(1, int(np.ceil((b - a) / steps[gi] - 1e-9)))
            pieces.append(np.linspace(a, b, n + 1)[:-1])
        return np.concatenate(pieces + [[road.length]])

    def to_mesh(self, materials, *, surface: str = "asphalt_dry", first_object_id: int = 1,
                names: dict[int, str] | None = None) -> TriangleMesh:  # fmt: skip
        """Triangulate every road: lane surfaces, markings (+2 mm, retro paint), guard rails.

        ``materials`` is a :class:`~lidar_weather_sim.scene.materials.MaterialTable` with
        ``surface``, ``lane_marking``, ``guard_rail`` (and ``concrete``/``vegetation``
        for sidewalk/median lanes). Object ids count up from ``first_object_id``: per
        road its surface, then its markings, then each guard rail; ``names`` (if
        given) is filled with id -> description. Normals of surfaces point up.
        """
        ids = iter(range(first_object_id, 2**32))
        names = {} if names is None else names
        meshes = []

        def emit(parts, material: str, label: str) -> None:
            parts = [p for p in parts if len(p[1])]
            if parts:
                oid = next(ids)
                names[oid] = label
                mat = materials.index(material)
                meshes.extend(TriangleMesh(V, T, mat, oid) for V, T in parts)

        up = np.array([0.0, 0.0, 1.0])
        for road in self.roads.values():
            grid = self.sample_s(road.id)
            surface_parts: dict[str, list] = {}
            mark_parts, rail_parts = [], []
            for sec in road.sections:
                ss = grid[(grid >= sec.s0 - 1e-9) & (grid <= sec.s1 + 1e-9)]
                if len(ss) >= 2:
                    f, b = road.frame(ss), road.borders(sec, ss)
                    for lid, lane in sec.lanes.items():
                        inner = lid - int(np.sign(lid))
                        if lid == 0 or lane.type in _NO_SURFACE or np.all(np.abs(b[lid] - b[inner]) < 1e-6):
                            continue
                        mat = _LANE_TYPE_MATERIAL.get(lane.type, surface)
                        surface_parts.setdefault(mat, []).append(
                            _strip(_Road.point(f, b[inner])[None], _Road.point(f, b[lid])[None], up))
                for lane in sec.lanes.values():
                    for mark in lane.marks:
                        mark_parts += self._mark_parts(road, sec, lane.id, mark, up)
            for rail in road.rails:
                rail_parts.append(self._rail_parts(road, rail, grid))
            for mat, parts in surface_parts.items():
                emit(parts, mat, f"road {road.id} surface ({mat})")
            emit(mark_parts, "lane_marking", f"road {road.id} lane markings")
            for rail, parts in zip(road.rails, rail_parts):
                emit(parts, "guard_rail", rail.name)
        return TriangleMesh.concatenate(meshes)

    def _mark_parts(self, road: _Road, sec: _Section, lane_id: int, mark: _Mark, up: np.ndarray) -> list:
        steps = [g.step for g in road.plan.geoms if g.s0 < mark.s1 and g.s0 + g.length > mark.s0] or [MAX_STEP_M]
        step = min(steps)
        parts = []
        for length, space, t_off, s_off, width in mark.lines:
            start = mark.s0 + s_off
            if space <= 0:
                a, b = np.array([start]), np.array([mark.s1])
            else:
                a = start + np.arange(max(0, int(np.ceil((mark.s1 - start) / (length + space))))) * (length + space)
                b = np.minimum(a + length, mark.s1)
            keep = b - a > 1e-3
            a, b = a[keep], b[keep]
            if not len(a):
                continue
            n = max(2, int(np.ceil((b - a).max() / step - 1e-9)) + 1)
            s = a[:, None] + (b - a)[:, None] * np.linspace(0.0, 1.0, n)[None, :]
            f, t = road.frame(s), road.borders(sec, s)[lane_id] + t_off
            lift = np.array([0.0, 0.0, MARK_LIFT_M])
            parts.append(_strip(_Road.point(f, t - 0.5 * width) + lift, _Road.point(f, t + 0.5 * width) + lift, up))
        return parts

    def _rail_parts(self, road: _Road, rail: _Rail, grid: np.ndarray) -> list:
        if rail.polyline is not None:
            pl = rail.polyline
            seg = np.linalg.norm(np.diff(pl[:, :2], axis=0), axis=1)
            arc = np.concatenate([[0.0], np.cumsum(seg)])
            q = np.unique(np.concatenate([arc, np.linspace(0, arc[-1], int(np.ceil(arc[-1] / MAX_STEP_M)) + 1)]))
            pl = np.column_stack([np.interp(q, arc, pl[:, j]) for j in range(5)])
            return _rail_mesh(pl[:, :3], pl[:, 3], pl[:, 4], self._nearest_ref(road, pl[len(pl) // 2, :2]))
        if rail.knots is not None:
            kn = rail.knots
            lo, hi = max(kn[0, 0], 0.0), min(kn[-1, 0], road.length)
            s = np.unique(np.concatenate([[lo, hi], kn[:, 0].clip(lo, hi), grid[(grid > lo) & (grid < hi)]]))
            t, bottom, top = (np.interp(s, kn[:, 0], kn[:, j]) for j in (1, 2, 3))
        else:
            s = grid
            isec = road.section_index(s)
            t = np.empty_like(s)
            for k in np.unique(isec):
                m, sec = isec == k, road.sections[k]
                outer = max((i * rail.edge_side for i in sec.lanes), default=0) * rail.edge_side
                t[m] = road.borders(sec, s[m])[outer] + rail.edge_side * rail.edge_gap
            bottom, top = np.full_like(s, RAIL_TOP_M - RAIL_BEAM_M), np.full_like(s, RAIL_TOP_M)
        f = road.frame(s)
        ref = _Road.point(f, np.zeros_like(s))
        return _rail_mesh(_Road.point(f, t), bottom, top, ref[len(s) // 2, :2])

    @staticmethod
    def _nearest_ref(road: _Road, xy: np.ndarray) -> np.ndarray:
        """Reference-line point nearest to ``xy`` (coarse search): the side a rail faces."""
        s = np.linspace(0.0, road.length, max(2, int(road.length / MAX_STEP_M) + 1))
        ref = _Road.point(road.frame(s), np.zeros_like(s))[:, :2]
        return ref[int(np.argmin(np.linalg.norm(ref - xy, axis=1)))]


@numba.njit(cache=True)
def _lane_index(lanes):
    """The distinct lane ids of ``lanes`` (ascending) and each element's index into them
    (``np.unique(lanes, return_inverse=True)`` for the few lanes, in runs, of a lane-pose call)."""
    ids = np.empty(0, np.int64)
    for i in range(len(lanes)):
        if i == 0 or lanes[i] != lanes[i - 1]:
            k = np.searchsorted(ids, lanes[i])
            if k == len(ids) or ids[k] != lanes[i]:
                ids = np.concatenate((ids[:k], lanes[i : i + 1], ids[k:]))
    index = np.empty(len(lanes), np.int64)
    for i in range(len(lanes)):
        index[i] = np.searchsorted(ids, lanes[i]) if i == 0 or lanes[i] != lanes[i - 1] else index[i - 1]
    return ids, index
