"""Turn an abstract road graph (nodes + roads) into a :class:`~.model.Town`.

Templates (``templates.py``) only decide *where* roads and junctions go; this module builds the
lanes, junction connectors (smooth cubic curves), lane graph, sidewalks, crosswalks, parking,
signals with phase plans, stop signs and buildings, the same way for every template.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.geometry import (
    offset_polyline,
    polyline_lengths,
    resample_polyline,
    world_to_local_2d,
    wrap_angle,
)
from .model import (
    CONNECTOR,
    DRIVING,
    LEFT,
    MERGE,
    PARKING,
    PRIORITY,
    RAMP,
    RIGHT,
    SIGNAL,
    STOP,
    STRAIGHT,
    Crosswalk,
    Junction,
    Lane,
    Sidewalk,
    Town,
)

END = -1  # node control for a dead end (map boundary)
PARKING_WIDTH = 2.5  # m
SIDEWALK_WIDTH = 3.0  # m
CROSSWALK_WIDTH = 4.0  # m
TURN_SPEED = 6.0  # m/s, speed limit on turning connectors
#: rad: arms closer than this (skewed junctions) push the junction's radius out
NARROW_ARM_GAP = np.radians(80.0)


@dataclass
class Node:
    """A road-graph node: junction, merge/diverge point, bend or dead end."""

    id: int
    pos: tuple[float, float]
    control: int = SIGNAL  # SIGNAL | STOP | PRIORITY | MERGE | END
    minor_roads: set[int] = field(default_factory=set)  # for PRIORITY: roads that must stop


@dataclass
class Road:
    """A road from node ``a`` to node ``b`` (``lanes_fwd`` run a->b, ``lanes_bwd`` b->a)."""

    id: int
    a: int
    b: int
    lanes_fwd: int = 1
    lanes_bwd: int = 1
    lane_width: float = 3.5
    speed_limit: float = 13.9  # m/s (50 km/h)
    parking: bool = False
    sidewalks: bool = True
    midblock_crosswalks: tuple[float, ...] = ()  # fractions along the road
    kind: int = DRIVING  # DRIVING | RAMP
    via: tuple[tuple[float, float], ...] = ()  # intermediate centre-line points (curves)


def _offset(points: np.ndarray, d: float) -> np.ndarray:
    """Offset a polyline ``(P, 2)`` by ``d`` metres to its right (negative: left)."""
    return offset_polyline(points, -d)


def _trim(points: np.ndarray, s0: float, s1: float, step: float = 2.0) -> np.ndarray:
    """Part of a polyline between arc lengths ``s0`` and ``L - s1``, resampled."""
    s = polyline_lengths(points)
    t = np.linspace(s0, s[-1] - s1, max(2, int(np.ceil((s[-1] - s1 - s0) / step)) + 1))
    return np.stack([np.interp(t, s, points[:, 0]), np.interp(t, s, points[:, 1])], -1)


def _bezier(p0, h0, p3, h3, step: float = 1.0) -> np.ndarray:
    d = float(np.linalg.norm(p3 - p0))
    k = 0.42 * d
    p1 = p0 + k * np.array([np.cos(h0), np.sin(h0)])
    p2 = p3 - k * np.array([np.cos(h3), np.sin(h3)])
    t = np.linspace(0.0, 1.0, max(8, int(d * 2)))[:, None]
    pts = (1 - t) ** 3 * p0 + 3 * (1 - t) ** 2 * t * p1 + 3 * (1 - t) * t**2 * p2 + t**3 * p3
    return resample_polyline(pts, step)


def _heading(points: np.ndarray, end: bool) -> float:
    d = points[-1] - points[-2] if end else points[1] - points[0]
    return float(np.arctan2(d[1], d[0]))


def _half_width(r: Road, side: str) -> float:
    n = r.lanes_fwd if side == "right" else r.lanes_bwd
    if r.lanes_bwd == 0:  # one-way: centred
        n = r.lanes_fwd / 2.0
    return n * r.lane_width + (PARKING_WIDTH if r.parking else 0.0)


class _Builder:
    def __init__(self, nodes: list[Node], roads: list[Road], rng: np.random.Generator):
        self.nodes, self.roads, self.rng = nodes, roads, rng
        self.lanes: list[Lane] = []
        self.crosswalks: list[Crosswalk] = []
        self.sidewalks: list[Sidewalk] = []
        self.parking: list[tuple[float, float, float]] = []
        # per (road, node) arm: incoming / outgoing lane ids ordered inner -> outer
        self.arm_in: dict[tuple[int, int], list[int]] = {}
        self.arm_out: dict[tuple[int, int], list[int]] = {}
        self.degree = np.zeros(len(nodes), dtype=int)
        for r in roads:
            self.degree[r.a] += 1
            self.degree[r.b] += 1
        self.radius = np.array([self._node_radius(n) for n in nodes])

    def _node_radius(self, n: Node) -> float:
        inc = [r for r in self.roads if n.id in (r.a, r.b)]
        if n.control == END or not inc:
            return 0.0
        if n.control == MERGE:
            return 25.0
        hw = max(max(_half_width(r, "right"), _half_width(r, "left")) for r in inc)
        if self.degree[n.id] == 2:
            return hw + 4.0
        gap = self._min_arm_gap(n, inc)
        if gap < NARROW_ARM_GAP:  # skewed arms: far enough out that their carriageways part
            return max(hw + 3.0, hw / np.tan(gap / 2.0) + 1.0)
        return hw + 3.0

    def _min_arm_gap(self, n: Node, inc: list[Road]) -> float:
        """Smallest angle (rad) between two arms of node ``n``, each arm's direction taken from
        the node to its road's centre line 10 m out (so ``via`` bends near the node count)."""
        p = np.array(n.pos, float)
        dirs = []
        for r in inc:
            pts = [np.array(q, float) for q in (self.nodes[r.a].pos, *r.via, self.nodes[r.b].pos)]
            line = np.array(pts if r.a == n.id else pts[::-1])
            s = polyline_lengths(line)
            q = np.array([np.interp(10.0, s, line[:, 0]), np.interp(10.0, s, line[:, 1])])
            dirs.append(float(np.arctan2(q[1] - p[1], q[0] - p[0])))
        a = np.sort(np.asarray(dirs) % (2 * np.pi))
        return float(np.min(np.diff(np.append(a, a[0] + 2 * np.pi)))) if len(a) > 1 else np.pi

    def add_lane(self, points: np.ndarray, **kw) -> int:
        lane = Lane(id=len(self.lanes), points=np.asarray(points, dtype=np.float64), **kw)
        self.lanes.append(lane)
        return lane.id

    # ------------------------------------------------------------------ roads
    def build_roads(self) -> None:
        for r in self.roads:
            pa, pb = np.array(self.nodes[r.a].pos, float), np.array(self.nodes[r.b].pos, float)
            centre = np.array([pa, *[np.array(v, float) for v in r.via], pb])
            centre = resample_polyline(centre, 2.0)
            centre = _trim(centre, self.radius[r.a], self.radius[r.b])
            w = r.lane_width
            shift = -r.lanes_fwd * w / 2.0 if r.lanes_bwd == 0 else 0.0
            fwd = [
                self.add_lane(_offset(centre, shift + (k + 0.5) * w), width=w, speed_limit=r.speed_limit,
                              kind=r.kind, road=r.id)
                for k in range(r.lanes_fwd)
            ]
            bwd = [
                self.add_lane(_offset(centre, -(k + 0.5) * w)[::-1].copy(), width=w,
                              speed_limit=r.speed_limit, kind=r.kind, road=r.id)
                for k in range(r.lanes_bwd)
            ]
            for group in (fwd, bwd):
                for k, lid in enumerate(group):
                    self.lanes[lid].left = group[k - 1] if k > 0 else -1
                    self.lanes[lid].right = group[k + 1] if k + 1 < len(group) else -1
            if fwd and bwd:
                self.lanes[fwd[0]].opposite = bwd[0]
                self.lanes[bwd[0]].opposite = fwd[0]
            self.arm_in[(r.id, r.b)], self.arm_out[(r.id, r.b)] = fwd, bwd
            self.arm_in[(r.id, r.a)], self.arm_out[(r.id, r.a)] = bwd, fwd
            self._road_side_features(r, centre, shift)

    def _road_side_features(self, r: Road, centre: np.ndarray, shift: float) -> None:
        w = r.lane_width
        length = polyline_lengths(centre)[-1]
        sides = [("right", 1.0, r.lanes_fwd * w + shift)]
        if r.lanes_bwd > 0:
            sides.append(("left", -1.0, r.lanes_bwd * w))
        else:
            sides.append(("left", -1.0, r.lanes_fwd * w / 2.0))
        cw_s = [f * length for f in r.midblock_crosswalks]
        for _name, sign, edge in sides:
            edge = edge if sign > 0 else edge
            if r.parking:
                pl = _offset(centre, sign * (edge + PARKING_WIDTH / 2.0))
                if sign < 0:
                    pl = pl[::-1].copy()
                self.add_lane(pl, width=PARKING_WIDTH, speed_limit=2.0, kind=PARKING, road=r.id)
                s = polyline_lengths(pl)
                for sp in np.arange(6.0, s[-1] - 6.0, 6.5):
                    if any(abs((s[-1] - sp if sign < 0 else sp) - c) < 5.0 for c in cw_s):
                        continue
                    i = int(np.searchsorted(s, sp))
                    h = _heading(pl[max(i - 1, 0): i + 1], end=True) if i > 0 else _heading(pl, False)
                    self.parking.append((float(np.interp(sp, s, pl[:, 0])), float(np.interp(sp, s, pl[:, 1])), h))
                edge += PARKING_WIDTH
            if r.sidewalks:
                sw = _offset(centre, sign * (edge + SIDEWALK_WIDTH / 2.0))
                self.sidewalks.append(Sidewalk(len(self.sidewalks), sw, SIDEWALK_WIDTH, r.id))
        # crosswalks: mid-block, and at both ends next to real junctions
        hw_r, hw_l = _half_width(r, "right"), _half_width(r, "left")
        spots = list(cw_s)
        for node, s in ((r.a, CROSSWALK_WIDTH / 2.0), (r.b, length - CROSSWALK_WIDTH / 2.0)):
            if self.degree[node] >= 3 and self.nodes[node].control not in (MERGE, END) and r.sidewalks:
                spots.append(s)
        sc = polyline_lengths(centre)
        for s in spots:
            s0, s1 = max(s - CROSSWALK_WIDTH / 2, 0.0), min(s + CROSSWALK_WIDTH / 2, length)
            p0 = np.array([np.interp(s0, sc, centre[:, 0]), np.interp(s0, sc, centre[:, 1])])
            p1 = np.array([np.interp(s1, sc, centre[:, 0]), np.interp(s1, sc, centre[:, 1])])
            t = (p1 - p0) / max(np.linalg.norm(p1 - p0), 1e-9)
            right = np.array([t[1], -t[0]])
            corners = np.array([p1 - hw_l * right, p0 - hw_l * right, p0 + hw_r * right, p1 + hw_r * right])
            junction = -1 if s in cw_s else -2  # resolved to the junction id later
            self.crosswalks.append(Crosswalk(len(self.crosswalks), corners, junction, r.id))

    # ------------------------------------------------------------------ junctions
    def build_junctions(self) -> list[Junction]:
        junctions: list[Junction] = []
        for n in self.nodes:
            arms = [(r.id, n.id) for r in self.roads if n.id in (r.a, r.b)]
            if n.control == END or len(arms) < 2:
                continue
            jid = len(junctions)
            centre = np.array(n.pos, float)
            j = Junction(id=jid, center=centre, radius=float(self.radius[n.id]) + 1.0, control=n.control)
            angle = {}
            for arm in arms:
                lanes = self.arm_in[arm] or self.arm_out[arm]
                ln = self.lanes[lanes[0]]
                p = ln.points[-1] if arm in self.arm_in and self.arm_in[arm] else ln.points[0]
                angle[arm] = float(np.arctan2(*(p - centre)[::-1]))
            for a_in in arms:
                for a_out in arms:
                    if a_in == a_out:
                        continue
                    self._connect(j, n, a_in, a_out, angle, len(arms))
            for arm in arms:
                for lid in self.arm_in[arm]:
                    lane = self.lanes[lid]
                    lane.junction_ahead = jid
                    j.incoming.append(lid)
                    stops = n.control == STOP or (n.control == PRIORITY and arm[0] in n.minor_roads)
                    if stops:
                        j.stop_lanes.append(lid)
                    lane.stop_at_end = stops or n.control == SIGNAL
            if n.control == SIGNAL:
                j.phase_groups = [list(self.arm_in[a]) for a in arms if self.arm_in[a]]
                j.green_s = float(self.rng.uniform(8.0, 12.0))
                j.yellow_s, j.all_red_s = 2.0, 1.5
                j.offset_s = float(self.rng.uniform(0.0, j.cycle_s))
            for c in self.crosswalks:
                if c.junction == -2 and np.linalg.norm(c.corners.mean(0) - centre) < j.radius + CROSSWALK_WIDTH + 8:
                    c.junction = jid
            junctions.append(j)
        for c in self.crosswalks:
            if c.junction == -2:
                c.junction = -1
        return junctions

    def _connect(self, j: Junction, n: Node, a_in, a_out, angle, n_arms: int) -> None:
        ins, outs = self.arm_in[a_in], self.arm_out[a_out]
        if not ins or not outs:
            return
        travel = angle[a_in] + np.pi  # heading when entering the junction
        delta = float(wrap_angle(angle[a_out] - travel))
        if n.control == MERGE and abs(delta) > np.pi / 3:
            return  # merges and diverges only connect carriageways heading the same way
        if n_arms == 2 or abs(delta) < np.pi / 5:
            turn = STRAIGHT
        elif abs(delta) > np.pi * 0.9:
            return  # no U-turns
        else:
            turn = LEFT if delta > 0 else RIGHT
        if n.control == MERGE:
            pairs = self._merge_pairs(a_in, a_out, ins, outs, turn)
        elif turn == STRAIGHT:
            pairs = [(ins[k], outs[k]) for k in range(min(len(ins), len(outs)))]
        elif turn == LEFT:
            pairs = [(ins[0], outs[0])]
        else:
            pairs = [(ins[-1], outs[-1])]
        for li, lo in pairs:
            p0, p3 = self.lanes[li].points[-1], self.lanes[lo].points[0]
            h0, h3 = _heading(self.lanes[li].points, True), _heading(self.lanes[lo].points, False)
            pts = _bezier(p0, h0, p3, h3)
            speed = self.lanes[li].speed_limit if turn == STRAIGHT else TURN_SPEED
            cid = self.add_lane(pts, width=self.lanes[li].width, speed_limit=speed, kind=CONNECTOR,
                                junction=j.id, turn=turn if n_arms > 2 or n.control == MERGE else STRAIGHT)
            self.lanes[li].successors.append(cid)
            self.lanes[cid].successors.append(lo)
            j.connectors.append(cid)

    def _merge_pairs(self, a_in, a_out, ins, outs, turn):
        r_in, r_out = self.roads[a_in[0]], self.roads[a_out[0]]
        if r_in.kind == RAMP and r_out.kind == RAMP:
            return []
        if r_in.kind == RAMP:  # on-ramp merges into the outermost lane
            return [(ins[-1], outs[-1])]
        if r_out.kind == RAMP:  # off-ramp diverges from the outermost lane
            return [(ins[-1], outs[-1])]
        return [(ins[k], outs[k]) for k in range(min(len(ins), len(outs)))]

    # ------------------------------------------------------------------ statics
    def poles(self, junctions: list[Junction]) -> tuple[np.ndarray, np.ndarray]:
        lights, stops = [], []
        for j in junctions:
            for lid in j.incoming:
                ln = self.lanes[lid]
                h = _heading(ln.points, True)
                p = ln.points[-1] - (CROSSWALK_WIDTH + 0.5) * np.array([np.cos(h), np.sin(h)])
                p = p + (ln.width / 2 + 0.6) * np.array([np.sin(h), -np.cos(h)])
                if ln.right != -1:
                    continue  # one pole per approach, on the outermost lane
                row = (p[0], p[1], float(wrap_angle(h + np.pi)), float(lid))
                if j.control == SIGNAL:
                    lights.append(row)
                elif lid in j.stop_lanes:
                    stops.append(row)
        return np.array(lights, float).reshape(-1, 4), np.array(stops, float).reshape(-1, 4)

    def buildings(self) -> tuple[np.ndarray, np.ndarray]:
        pts = [ln.points for ln in self.lanes] + [s.points for s in self.sidewalks]
        occupied = np.concatenate(pts, 0)
        boxes: list[tuple[float, float, float, float, float]] = []
        heights: list[float] = []
        for sw in self.sidewalks:
            s = polyline_lengths(sw.points)
            for sp in np.arange(4.0, s[-1], 9.0):
                depth = float(self.rng.uniform(8.0, 16.0))
                length = float(self.rng.uniform(10.0, 22.0))
                i = min(int(np.searchsorted(s, sp)), len(s) - 1)
                h = _heading(sw.points[max(i - 1, 0): max(i, 1) + 1], end=True)
                p = np.array([np.interp(sp, s, sw.points[:, 0]), np.interp(sp, s, sw.points[:, 1])])
                for side in (1.0, -1.0):
                    nrm = side * np.array([np.sin(h), -np.cos(h)])
                    c = p + nrm * (SIDEWALK_WIDTH / 2 + 1.5 + depth / 2)
                    local = world_to_local_2d(occupied, c, h)
                    if np.any((np.abs(local[:, 0]) < length / 2 + 1.5) & (np.abs(local[:, 1]) < depth / 2 + 1.5)):
                        continue
                    if boxes:
                        b = np.array(boxes)
                        if np.any(np.linalg.norm(b[:, :2] - c, axis=1) < 0.5 * (length + b[:, 2]) * 0.9):
                            continue
                    boxes.append((float(c[0]), float(c[1]), length, depth, h))
                    heights.append(float(self.rng.uniform(6.0, 25.0)))
        return np.array(boxes, float).reshape(-1, 5), np.array(heights, float)


def build_town(name: str, template: str, seed: int, nodes: list[Node], roads: list[Road],
               rng: np.random.Generator) -> Town:
    """Build a :class:`Town` from a road graph (see module docstring)."""
    b = _Builder(nodes, roads, rng)
    b.build_roads()
    junctions = b.build_junctions()
    for lane in b.lanes:
        for s in lane.successors:
            b.lanes[s].predecessors.append(lane.id)
    lights, stops = b.poles(junctions)
    buildings, heights = b.buildings()
    allp = np.concatenate([ln.points for ln in b.lanes], 0)
    bounds = np.array([*(allp.min(0) - 40.0), *(allp.max(0) + 40.0)])
    return Town(
        name=name, template=template, seed=seed, lanes=b.lanes, junctions=junctions,
        crosswalks=b.crosswalks, sidewalks=b.sidewalks,
        parking=np.array(b.parking, float).reshape(-1, 3), buildings=buildings,
        building_heights=heights, lights=lights, stop_signs=stops, bounds=bounds,
    )
