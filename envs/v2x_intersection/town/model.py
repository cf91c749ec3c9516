"""Road-network data model: lanes with a lane graph, junctions, signals, crosswalks, buildings.

A :class:`Town` is plain data; it serializes to JSON (:meth:`Town.to_dict`) and loads back
identical (:meth:`Town.from_dict`). Derived, vectorized lookup tables live in
:class:`LaneIndex` (built once per town, never serialized).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.geometry import polyline_lengths
from ..core.jit import HAVE_JIT, pose_at_kernel, project_kernel

# Lane kinds
DRIVING, CONNECTOR, PARKING, RAMP = 0, 1, 2, 3
LANE_KIND_NAMES = ("driving", "connector", "parking", "ramp")

# Turn / navigation command codes (as CARLA's RoadOption)
FOLLOW_LANE, LEFT, RIGHT, STRAIGHT, CHANGE_LANE_LEFT, CHANGE_LANE_RIGHT = 0, 1, 2, 3, 4, 5
COMMAND_NAMES = ("follow_lane", "left", "right", "straight", "change_lane_left", "change_lane_right")

# Junction control
SIGNAL, STOP, PRIORITY, MERGE = 0, 1, 2, 3
CONTROL_NAMES = ("signal", "stop", "priority", "merge")
STOP_LINE_SETBACK = 4.5  # m, stop line before the lane end (crosswalk + margin)


@dataclass
class Lane:
    """A directed lane centre line.

    Attributes:
        id: index in ``Town.lanes``.
        points: ``(P, 2)`` centre-line polyline in driving direction (m).
        width: lane width (m).
        speed_limit: (m/s).
        kind: ``DRIVING | CONNECTOR | PARKING | RAMP``.
        road: id of the road it belongs to (-1 for junction connectors).
        junction: id of the junction it crosses (-1 outside junctions).
        turn: for connectors the manoeuvre (``LEFT | RIGHT | STRAIGHT``), else ``FOLLOW_LANE``.
        successors, predecessors: lane ids in the lane graph.
        left, right: same-direction neighbour lane ids (-1: none).
        opposite: the adjacent lane of the opposite direction on a two-way road (-1: none).
        stop_at_end: the lane ends at a stop line (signal or stop sign) of ``junction_ahead``.
        junction_ahead: junction at the end of the lane (-1: none).
    """

    id: int
    points: np.ndarray
    width: float = 3.5
    speed_limit: float = 13.9
    kind: int = DRIVING
    road: int = -1
    junction: int = -1
    turn: int = FOLLOW_LANE
    successors: list[int] = field(default_factory=list)
    predecessors: list[int] = field(default_factory=list)
    left: int = -1
    right: int = -1
    opposite: int = -1
    stop_at_end: bool = False
    junction_ahead: int = -1

    @property
    def length(self) -> float:
        """Arc length (m)."""
        return float(polyline_lengths(self.points)[-1])


@dataclass
class Junction:
    """A junction (or a merge/diverge node on a highway).

    Attributes:
        id: index in ``Town.junctions``.
        center: ``(2,)`` position (m).
        radius: extent of the conflict area from the centre (m).
        control: ``SIGNAL | STOP | PRIORITY | MERGE``.
        incoming: ids of lanes ending at this junction.
        connectors: ids of connector lanes inside it.
        phase_groups: for signals, lists of incoming lane ids that are green together.
        green_s, yellow_s, all_red_s: phase timing (s).
        offset_s: phase offset (s) so junctions are not synchronized.
        stop_lanes: incoming lanes with a stop sign.
    """

    id: int
    center: np.ndarray
    radius: float
    control: int
    incoming: list[int] = field(default_factory=list)
    connectors: list[int] = field(default_factory=list)
    phase_groups: list[list[int]] = field(default_factory=list)
    green_s: float = 12.0
    yellow_s: float = 3.0
    all_red_s: float = 1.0
    offset_s: float = 0.0
    stop_lanes: list[int] = field(default_factory=list)

    @property
    def cycle_s(self) -> float:
        """Length of one full signal cycle (s)."""
        return len(self.phase_groups) * (self.green_s + self.yellow_s + self.all_red_s)


@dataclass
class Crosswalk:
    """A zebra crossing: ``corners (4, 2)``; ``junction`` -1 for mid-block crossings."""

    id: int
    corners: np.ndarray
    junction: int = -1
    road: int = -1


@dataclass
class Sidewalk:
    """A pedestrian path polyline ``(P, 2)`` beside a road."""

    id: int
    points: np.ndarray
    width: float = 3.0
    road: int = -1


@dataclass
class Town:
    """A generated road network and its static world.

    Attributes:
        name, template, seed: identity; ``(template, seed)`` regenerates it.
        lanes, junctions, crosswalks, sidewalks: the road network.
        parking: ``(K, 3)`` parking slots ``(x, y, yaw)``.
        buildings: ``(B, 5)`` boxes ``(x, y, length, width, yaw)`` with ``building_heights (B,)``.
        lights: ``(L, 4)`` traffic-light poles ``(x, y, yaw, lane_id)`` (the lane they control).
        stop_signs: ``(S, 4)`` stop-sign poles ``(x, y, yaw, lane_id)``.
        bounds: ``(4,)`` ``xmin, ymin, xmax, ymax`` (m).
    """

    name: str
    template: str
    seed: int
    lanes: list[Lane]
    junctions: list[Junction]
    crosswalks: list[Crosswalk]
    sidewalks: list[Sidewalk]
    parking: np.ndarray
    buildings: np.ndarray
    building_heights: np.ndarray
    lights: np.ndarray
    stop_signs: np.ndarray
    bounds: np.ndarray
    _index: LaneIndex | None = field(default=None, repr=False, compare=False)

    @property
    def index(self) -> LaneIndex:
        """Vectorized lane lookup tables (built on first use)."""
        if self._index is None:
            self._index = LaneIndex(self)
        return self._index

    def cache(self, name: str) -> dict:
        """A dict kept on the town for tables derived from it (a town does not change once built,
        so what is computed from it once can live with it): ``town.cache("major_masks")``."""
        return self.__dict__.setdefault(f"_cache_{name}", {})

    # ----------------------------------------------------------------- serialization
    def to_dict(self) -> dict:
        """JSON-compatible dict (lists of floats); :meth:`from_dict` restores it exactly."""

        def arr(a: np.ndarray) -> list:
            return np.asarray(a, dtype=np.float64).tolist()

        return {
            "format": "v2xbench-town/1",
            "name": self.name,
            "template": self.template,
            "seed": int(self.seed),
            "lanes": [
                {
                    "id": ln.id,
                    "points": arr(ln.points),
                    "width": ln.width,
                    "speed_limit": ln.speed_limit,
                    "kind": LANE_KIND_NAMES[ln.kind],
                    "road": ln.road,
                    "junction": ln.junction,
                    "turn": COMMAND_NAMES[ln.turn],
                    "successors": list(ln.successors),
                    "predecessors": list(ln.predecessors),
                    "left": ln.left,
                    "right": ln.right,
                    "opposite": ln.opposite,
                    "stop_at_end": ln.stop_at_end,
                    "junction_ahead": ln.junction_ahead,
                }
                for ln in self.lanes
            ],
            "junctions": [
                {
                    "id": j.id,
                    "center": arr(j.center),
                    "radius": j.radius,
                    "control": CONTROL_NAMES[j.control],
                    "incoming": list(j.incoming),
                    "connectors": list(j.connectors),
                    "phase_groups": [list(g) for g in j.phase_groups],
                    "green_s": j.green_s,
                    "yellow_s": j.yellow_s,
                    "all_red_s": j.all_red_s,
                    "offset_s": j.offset_s,
                    "stop_lanes": list(j.stop_lanes),
                }
                for j in self.junctions
            ],
            "crosswalks": [
                {"id": c.id, "corners": arr(c.corners), "junction": c.junction, "road": c.road}
                for c in self.crosswalks
            ],
            "sidewalks": [
                {"id": s.id, "points": arr(s.points), "width": s.width, "road": s.road}
                for s in self.sidewalks
            ],
            "parking": arr(self.parking),
            "buildings": arr(self.buildings),
            "building_heights": arr(self.building_heights),
            "lights": arr(self.lights),
            "stop_signs": arr(self.stop_signs),
            "bounds": arr(self.bounds),
        }

    @classmethod
    def from_dict(cls, d: dict) -> Town:
        """Inverse of :meth:`to_dict`; raises ``ValueError`` naming a missing or bad field."""
        if d.get("format") != "v2xbench-town/1":
            raise ValueError(f"town: unknown format {d.get('format')!r}, expected 'v2xbench-town/1'")
        try:
            lanes = [
                Lane(
                    id=int(x["id"]),
                    points=np.asarray(x["points"], dtype=np.float64).reshape(-1, 2),
                    width=float(x["width"]),
                    speed_limit=float(x["speed_limit"]),
                    kind=LANE_KIND_NAMES.index(x["kind"]),
                    road=int(x["road"]),
                    junction=int(x["junction"]),
                    turn=COMMAND_NAMES.index(x["turn"]),
                    successors=[int(i) for i in x["successors"]],
                    predecessors=[int(i) for i in x["predecessors"]],
                    left=int(x["left"]),
                    right=int(x["right"]),
                    opposite=int(x["opposite"]),
                    stop_at_end=bool(x["stop_at_end"]),
                    junction_ahead=int(x["junction_ahead"]),
                )
                for x in d["lanes"]
            ]
            junctions = [
                Junction(
                    id=int(x["id"]),
                    center=np.asarray(x["center"], dtype=np.float64),
                    radius=float(x["radius"]),
                    control=CONTROL_NAMES.index(x["control"]),
                    incoming=[int(i) for i in x["incoming"]],
                    connectors=[int(i) for i in x["connectors"]],
                    phase_groups=[[int(i) for i in g] for g in x["phase_groups"]],
                    green_s=float(x["green_s"]),
                    yellow_s=float(x["yellow_s"]),
                    all_red_s=float(x["all_red_s"]),
                    offset_s=float(x["offset_s"]),
                    stop_lanes=[int(i) for i in x["stop_lanes"]],
                )
                for x in d["junctions"]
            ]
            crosswalks = [
                Crosswalk(int(x["id"]), np.asarray(x["corners"], dtype=np.float64).reshape(4, 2),
                          int(x["junction"]), int(x["road"]))
                for x in d["crosswalks"]
            ]
            sidewalks = [
                Sidewalk(int(x["id"]), np.asarray(x["points"], dtype=np.float64).reshape(-1, 2),
                         float(x["width"]), int(x["road"]))
                for x in d["sidewalks"]
            ]

            def arr(key: str, cols: int) -> np.ndarray:
                return np.asarray(d[key], dtype=np.float64).reshape(-1, cols)

            return cls(
                name=str(d["name"]),
                template=str(d["template"]),
                seed=int(d["seed"]),
                lanes=lanes,
                junctions=junctions,
                crosswalks=crosswalks,
                sidewalks=sidewalks,
                parking=arr("parking", 3),
                buildings=arr("buildings", 5),
                building_heights=np.asarray(d["building_heights"], dtype=np.float64),
                lights=arr("lights", 4),
                stop_signs=arr("stop_signs", 4),
                bounds=np.asarray(d["bounds"], dtype=np.float64),
            )
        except KeyError as e:
            raise ValueError(f"town: missing field {e.args[0]!r}") from None
        except (TypeError, ValueError) as e:
            raise ValueError(f"town: malformed field value: {e}") from None


class PolylineIndex:
    """Flattened polylines for vectorized position lookup and nearest-point queries.

    All polylines are concatenated into one array of points; ``offset[l]`` is the index of
    polyline ``l``'s first point and ``gs`` a *global* arc length in which polyline ``l`` starts at
    ``base[l]`` (polylines separated by a 1 km gap), so one ``np.searchsorted`` serves all actors.
    """

    GAP = 1000.0

    def __init__(self, polylines: list[np.ndarray]) -> None:
        n_pts = np.array([len(p) for p in polylines])
        self.offset = np.concatenate([[0], np.cumsum(n_pts)[:-1]]).astype(np.int64)
        self.n_points = n_pts
        self.points = np.concatenate(polylines, 0)
        s_local = [polyline_lengths(p) for p in polylines]
        self.length = np.array([s[-1] for s in s_local])
        self.base = np.concatenate([[0.0], np.cumsum(self.length + self.GAP)[:-1]])
        self.gs = np.concatenate([s + b for s, b in zip(s_local, self.base)])
        seg = np.diff(self.points, axis=0)
        heading = np.arctan2(seg[:, 1], seg[:, 0])
        self.heading = np.concatenate([heading, heading[-1:]])
        last = self.offset + n_pts - 1  # a polyline's last point takes its previous segment heading
        self.heading[last] = self.heading[last - 1]
        self.owner = np.repeat(np.arange(len(polylines)), n_pts)

    def pose_at(self, idx: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions ``(N, 2)`` and headings ``(N,)`` at arc length ``s`` (m) on polylines ``idx``."""
        idx = np.asarray(idx)
        if HAVE_JIT and idx.ndim == 1 and idx.dtype.kind == "i":
            s = np.asarray(s, dtype=np.float64)
            if s.shape == idx.shape:
                return pose_at_kernel(idx.astype(np.int64, copy=False), s, self.points, self.heading, self.offset,
                                      self.n_points, self.gs, self.base, self.length)
        s = np.clip(np.asarray(s, dtype=np.float64), 0.0, self.length[idx])
        g = self.base[idx] + s
        first = self.offset[idx]
        last = first + self.n_points[idx] - 1
        i = np.clip(np.searchsorted(self.gs, g, side="right") - 1, first, last - 1)
        s0, s1 = self.gs[i], self.gs[i + 1]
        t = np.where(s1 > s0, (g - s0) / np.maximum(s1 - s0, 1e-9), 0.0)[..., None]
        p = self.points[i] * (1.0 - t) + self.points[i + 1] * t
        return p, self.heading[i]

    def point_ids(self, candidates: np.ndarray) -> np.ndarray:
        """Indices into ``points`` of all vertices of the polylines ``candidates``."""
        return np.concatenate([np.arange(self.offset[c], self.offset[c] + self.n_points[c]) for c in candidates])

    def lane_point_ids(self, lane: int) -> np.ndarray:
        """``point_ids([lane])`` for one polyline, cached (read-only)."""
        cache = self.__dict__.setdefault("_lane_pids", {})
        pid = cache.get(lane)
        if pid is None:
            pid = np.arange(self.offset[lane], self.offset[lane] + self.n_points[lane])
            pid.setflags(write=False)
            cache[lane] = pid
        return pid

    def project_near(self, xy: np.ndarray, point_ids: np.ndarray, radius: float = 10.0):
        """:meth:`project` of one query ``xy (2,)`` against ``point_ids``, with the same result,
        searching first only the points within ``radius`` m on each axis.

        Exact: when the nearest point of that square is closer than ``radius``, every point
        outside it is farther, so the full search would pick the same vertex (ties go to the
        first id, and the square keeps ``point_ids`` order). Otherwise it falls back to the full
        search.
        """
        if HAVE_JIT:  # the full search costs less than the square's set-up
            return self.project(xy, point_ids=point_ids)
        key = id(point_ids)
        cache = self.__dict__.setdefault("_near_cache", {})
        entry = cache.get(key)
        if entry is None or entry[0] is not point_ids:
            order = np.argsort(self.points[point_ids, 0], kind="stable")
            entry = (point_ids, order, self.points[point_ids[order], 0])
            cache[key] = entry
        _, order, xs = entry
        x, y = float(xy[0]), float(xy[1])
        lo, hi = np.searchsorted(xs, (x - radius, x + radius))
        sub = order[lo:hi]
        pts = self.points[point_ids[sub]]
        sub = sub[np.abs(pts[:, 1] - y) <= radius]
        if len(sub):
            d2 = ((np.asarray(xy, dtype=np.float64).reshape(1, 2) - self.points[point_ids[sub]]) ** 2).sum(-1)
            if d2.min() < radius * radius:
                return self.project(xy, point_ids=point_ids[np.sort(sub)])
        return self.project(xy, point_ids=point_ids)

    def project(self, xy: np.ndarray, candidates: np.ndarray | None = None,
                point_ids: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Nearest polyline point to each query ``xy (N, 2)``.

        Args:
            xy: query positions (m).
            candidates: optional polyline ids to restrict the search to.
            point_ids: precomputed ``point_ids(candidates)`` (faster on hot paths).

        Returns:
            ``(idx (N,), s (N,), dist (N,))``: polyline id, arc length on it, distance (m).
        """
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if point_ids is not None:
            pid = point_ids
        elif candidates is None:
            pid = np.arange(len(self.points))
        else:
            pid = self.point_ids(candidates)
        if HAVE_JIT and len(pid):
            return project_kernel(xy, self.points, np.asarray(pid, np.int64), self.owner, self.offset,
                                  self.n_points, self.gs, self.base)
        d2 = ((xy[:, None, :] - self.points[pid][None]) ** 2).sum(-1)
        j = pid[np.argmin(d2, axis=1)]
        owner = self.owner[j]
        first = self.offset[owner]
        last = first + self.n_points[owner] - 1
        best_s = self.gs[j] - self.base[owner]
        best_d = np.sqrt(((xy - self.points[j]) ** 2).sum(-1))
        for a, b in ((j, j + 1), (j - 1, j)):  # refine on the segments beside the vertex
            ok = (a >= first) & (b <= last)
            a = np.clip(a, 0, len(self.points) - 1)
            b = np.clip(b, 0, len(self.points) - 1)
            seg = self.points[b] - self.points[a]
            seg_len2 = np.maximum((seg**2).sum(-1), 1e-12)
            t = np.clip(((xy - self.points[a]) * seg).sum(-1) / seg_len2, 0.0, 1.0)
            q = self.points[a] + t[:, None] * seg
            d = np.sqrt(((xy - q) ** 2).sum(-1))
            s = self.gs[a] - self.base[owner] + t * np.sqrt(seg_len2)
            better = ok & (d < best_d)
            best_d = np.where(better, d, best_d)
            best_s = np.where(better, s, best_s)
        return owner, best_s, best_d


class LaneIndex(PolylineIndex):
    """:class:`PolylineIndex` over a town's lanes plus per-lane attribute arrays."""

    def __init__(self, town: Town) -> None:
        super().__init__([ln.points for ln in town.lanes])
        lanes = town.lanes
        self.width = np.array([ln.width for ln in lanes])
        self.speed_limit = np.array([ln.speed_limit for ln in lanes])
        self.kind = np.array([ln.kind for ln in lanes])
        self.junction = np.array([ln.junction for ln in lanes])
        self.stop_at_end = np.array([ln.stop_at_end for ln in lanes])
        self.junction_ahead = np.array([ln.junction_ahead for ln in lanes])
        self.turn = np.array([ln.turn for ln in lanes])
        self.left = np.array([ln.left for ln in lanes])
        self.right = np.array([ln.right for ln in lanes])
        self.n_successors = np.array([len(ln.successors) for ln in lanes])
