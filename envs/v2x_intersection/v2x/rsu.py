"""Route-adaptive roadside-unit deployment and per-tick active-unit selection (paper appendix).

Roadside units are infrastructure: their placement reads the town and the route only, never the
scenario list, so a unit's pose carries no information about where a hazard will be
(``tests/v2x/test_rsu.py`` checks that the poses are the same with and without scenarios).

Candidates are placed (1) every ~``STRAIGHT_SPACING`` m along the route's non-junction parts,
beside the road and looking back at the approaching ego; (2) at every junction the route crosses,
once per pass (a route that comes back to a junction arrives from another approach), on a corner
offset from the centre: the far-right corner (as seen when arriving), looking back
over the junction at the approach; where the route turns left there, a second unit on the
near-right corner, looking across the junction centre at the oncoming approach and the left exit
(the traffic a left turn crosses, behind the far-right unit). Units closer
than ``MIN_SPACING`` m to an already kept unit of their kind are pruned (a street unit looks along
the road, a junction unit over the junction: they do not replace each other; nor do the units of
two passes of one junction that arrive from different approaches, nor street units looking
opposite ways along the road, where a route comes back along a street). Each tick the
active unit is chosen from the ego's pose only: among the forward-facing units in range, the one
watching the road ``LOOKAHEAD_M`` m ahead of the ego (the point within its camera's view) most
directly (smallest angle off its axis plus distance to the point / ``SELECT_M_PER_RAD``: at a
left turn the unit looking across the junction at
the oncoming traffic, not the one looking back at the approach); else the nearest
forward-facing unit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core import libm
from ..core.geometry import pose_matrix, row_norms, wrap_angle
from ..core.jit import HAVE_JIT
from ..perception.jit_perception import (
    SELECT_M_PER_RAD,
    UNSEEN_KEY,
    select_active_kernel,
    sidewalk_snap_kernel,
)
from ..town.model import Town
from ..town.routes import Route

STRAIGHT_SPACING = 40.0  # m
MIN_SPACING = 20.0  # m
RSU_HEIGHT = 5.0  # m
RSU_PITCH = np.deg2rad(12.0)  # rad, pitched down toward the road
RSU_ROLL = np.deg2rad(1.0)  # rad, small roll offset (as the paper)
SIDE_OFFSET = 9.0  # m from the route centre line to the pole
STREET_AHEAD_M = 30.0  # m along the route from the point a street unit serves to where it stands
#: m before a junction's entry where a street unit stops short of it (clear of the corner)
JUNCTION_SETBACK_M = 10.0
#: rad: a junction unit looks this far from the junction centre, toward the approach it serves
#: (from the far-right corner: the near-right corner, where hidden walkers wait, in view)
JUNCTION_TURN = float(np.pi / 8)
#: rad: a route whose heading turns left by more than this through a junction turns left there
LEFT_TURN_MIN = float(np.pi / 4)
#: rad: street units whose yaws differ by more than this look opposite ways along the road
OPPOSITE_MIN = float(np.deg2rad(135.0))
SNAP_M = 8.0  # m: poles move to the nearest sidewalk point within this distance
KIND_STRAIGHT, KIND_JUNCTION = 0, 1
FACING_MAX_ANGLE = float(np.deg2rad(100.0))  # rad: a unit faces the ego within this angle
#: m: the active unit is chosen for the road this far ahead of the ego (where hazards matter)
LOOKAHEAD_M = 12.0
#: rad: half the view in which a unit counts as watching a point (the RSU camera's 90 deg FOV)
VIEW_HALF_ANGLE = float(np.deg2rad(45.0))


@dataclass
class RSUSet:
    """Deployed units of one route.

    Attributes:
        pose: ``(U, 4)`` ``(x, y, z, yaw)`` (m, rad); pitch ``RSU_PITCH``, roll ``RSU_ROLL``.
        kind: ``(U,)`` ``KIND_STRAIGHT | KIND_JUNCTION``.
        route_s: ``(U,)`` route arc length the unit was placed for (m).
    """

    pose: np.ndarray
    kind: np.ndarray
    route_s: np.ndarray

    def __len__(self) -> int:
        return len(self.pose)

    def matrix(self, u: int) -> np.ndarray:
        """4x4 ``T_world_rsu`` of unit ``u`` (RSU body frame: x along the optical axis, z up)."""
        x, y, z, yaw = self.pose[u]
        return pose_matrix(x, y, z, yaw, RSU_PITCH, RSU_ROLL)


DEPLOY_CACHE_SIZE = 256  # deployments remembered per town (episodes that replay a route reuse them)


def deploy(town: Town, route: Route) -> RSUSet:
    """Place RSUs for a route (see module docstring).

    The placement depends only on the town and the route's points, so it is remembered per town
    (the last :data:`DEPLOY_CACHE_SIZE` routes; the arrays are read-only).

    Args:
        town: the road network.
        route: the ego's route.
    """
    key = (route.points.tobytes(), route.lane_ids.tobytes())
    cache = town.cache("rsu_deployments")
    units = cache.get(key)
    if units is None:
        units = _deploy(town, route)
        for a in (units.pose, units.kind, units.route_s):
            a.setflags(write=False)
        while cache and len(cache) >= DEPLOY_CACHE_SIZE:
            cache.pop(next(iter(cache)))
        if DEPLOY_CACHE_SIZE > 0:
            cache[key] = units
    return units


def junction_passes(town: Town, route: Route) -> list[tuple[int, np.ndarray]]:
    """The route's passes through junctions, in route order: ``(junction id, indices)`` with the
    indices an unbroken run of route points inside that junction (a route that comes back to a
    junction crosses it twice: two passes, each arriving from its own approach)."""
    jl = town.index.junction[route.lane_ids]
    idx = np.flatnonzero(jl >= 0)
    if not len(idx):
        return []
    breaks = np.flatnonzero((np.diff(idx) > 1) | (np.diff(jl[idx]) != 0)) + 1
    return [(int(jl[run[0]]), run) for run in np.split(idx, breaks)]


def _deploy(town: Town, route: Route) -> RSUSet:
    cands: list[tuple[float, float, float, int, float]] = []
    pts, hd, s = route.points, route.headings, route.s
    in_junction = town.index.junction[route.lane_ids] >= 0
    turn_units: set[int] = set()  # the left-turn units (kept apart from the others)
    approach: dict[int, tuple[int, float]] = {}  # junction unit -> (junction id, arrival heading)
    # every pass through a junction (not every junction: a second pass arrives from another side)
    for jid, inside in junction_passes(town, route):
        j = town.junctions[jid]
        k = int(inside[np.argmin(np.linalg.norm(pts[inside] - j.center, axis=1))])
        h_in = hd[max(int(inside[0]) - 1, 0)]
        h_out = hd[min(int(inside[-1]) + 1, len(hd) - 1)]
        # far-right corner as seen when arriving, looking back over the junction at the approach
        corner = j.center + (j.radius + 3.0) * np.array([np.cos(h_in - np.pi / 4),
                                                          np.sin(h_in - np.pi / 4)])
        yaw = np.arctan2(*(j.center - corner)[::-1]) + JUNCTION_TURN
        if wrap_angle(h_out - h_in) > LEFT_TURN_MIN:
            # a left turn: also the near-right corner, looking across the junction centre at the
            # oncoming approach and the left exit (the far-right unit has them behind it)
            near = j.center + (j.radius + 3.0) * np.array([np.cos(h_in - 0.75 * np.pi),
                                                            np.sin(h_in - 0.75 * np.pi)])
            yaw_n = np.arctan2(*(j.center - near)[::-1])
            turn_units.add(len(cands))
            approach[len(cands)] = (jid, float(h_in))
            cands.append((near[0], near[1], float(yaw_n), KIND_JUNCTION, float(s[k]) - 1e-3))
        approach[len(cands)] = (jid, float(h_in))
        cands.append((corner[0], corner[1], float(yaw), KIND_JUNCTION, float(s[k])))
    for sk in np.arange(STRAIGHT_SPACING / 2, route.length, STRAIGHT_SPACING):
        k = int(np.searchsorted(s, sk))
        k = min(k, len(pts) - 1)
        if in_junction[k]:
            continue
        # the unit stands 30 m ahead of the point it serves, looking back at the ego; on the same
        # road: where a junction comes first, JUNCTION_SETBACK_M before it (past it, a turn would
        # leave the unit looking along another road; at the corner, buildings block the kerb)
        ahead = min(int(np.searchsorted(s, sk + STREET_AHEAD_M)), len(pts) - 1)
        reach = min(int(np.searchsorted(s, sk + STREET_AHEAD_M + JUNCTION_SETBACK_M)), len(pts) - 1)
        entry = in_junction[k : reach + 1].nonzero()[0]
        if len(entry):
            ahead = max(int(np.searchsorted(s, s[k + entry[0]] - JUNCTION_SETBACK_M)), k)
        p = _beside(pts[ahead], hd[ahead], SIDE_OFFSET)
        yaw = wrap_angle(hd[ahead] + np.pi - 0.35)
        cands.append((p[0], p[1], float(yaw), KIND_STRAIGHT, float(s[k])))
    cands = [_on_sidewalk(town, c) for c in cands]
    order = sorted(range(len(cands)), key=lambda i: (-cands[i][3], cands[i][4]))
    kept: list[int] = []
    for i in order:  # units of a kind keep their distance (a street unit looks along the road,
        # a junction unit over the junction: both are kept where they stand close together), but
        # two passes of one junction from different approaches keep their own units, and a
        # street unit looking back along the road does not replace one looking the other way
        # (a route that comes back along the street it drove)
        if all(
            np.hypot(cands[i][0] - cands[j][0], cands[i][1] - cands[j][1]) >= MIN_SPACING
            for j in kept if cands[j][3] == cands[i][3] and (j in turn_units) == (i in turn_units)
            and not _other_approach(approach.get(i), approach.get(j))
            and not (cands[i][3] == KIND_STRAIGHT and _opposite(cands[i][2], cands[j][2]))
        ):
            kept.append(i)
    kept.sort(key=lambda i: cands[i][4])
    c = np.array([cands[i] for i in kept], float).reshape(-1, 5)
    pose = np.stack([c[:, 0], c[:, 1], np.full(len(c), RSU_HEIGHT), c[:, 2]], -1)
    return RSUSet(pose, c[:, 3].astype(np.int64), c[:, 4])


def _opposite(yaw_a: float, yaw_b: float) -> bool:
    """Whether two units look opposite ways (yaws more than ``OPPOSITE_MIN`` apart)."""
    return abs(float(wrap_angle(yaw_a - yaw_b))) > OPPOSITE_MIN


def _other_approach(a: tuple[int, float] | None, b: tuple[int, float] | None) -> bool:
    """Whether two junction units serve the same junction arrived at from different approaches
    (arrival headings more than 45 deg apart)."""
    if a is None or b is None or a[0] != b[0]:
        return False
    return abs(float(wrap_angle(a[1] - b[1]))) > np.pi / 4


def _on_sidewalk(town: Town, cand: tuple) -> tuple:
    """Move a pole to the nearest sidewalk point within ``SNAP_M`` (poles stand on the kerb, never
    inside a building); keep the unit looking at the same spot."""
    if not town.sidewalks:
        return cand
    x, y, yaw, kind, s = cand
    idx = _sidewalk_index(town)
    if HAVE_JIT:  # both searches in one pass over the vertices (the same numbers)
        d, k = sidewalk_snap_kernel(float(x), float(y), idx.points, idx.owner, idx.offset, idx.n_points, idx.gs,
                                    idx.base)
        if d > SNAP_M:
            return cand
    else:
        _, _, dist = idx.project(np.array([[x, y]]))
        if dist[0] > SNAP_M:
            return cand
        k = np.argmin(np.linalg.norm(idx.points - (x, y), axis=1))
    nx, ny = idx.points[k]
    target = np.array([x, y]) + 20.0 * np.array([np.cos(yaw), np.sin(yaw)])
    return (float(nx), float(ny), float(np.arctan2(target[1] - ny, target[0] - nx)), kind, s)


def _sidewalk_index(town: Town):
    from ..town.model import PolylineIndex

    store = town.cache("sidewalks")
    if "index" not in store:
        store["index"] = PolylineIndex([sw.points for sw in town.sidewalks])
    return store["index"]


def _beside(p: np.ndarray, heading: float, offset: float) -> np.ndarray:
    return p + offset * np.array([np.sin(heading), -np.cos(heading)])


def select_active(rsus: RSUSet, ego_xy: np.ndarray, ego_yaw: float, max_range: float, slots: int = 1) -> np.ndarray:
    """Indices of the ``slots`` best forward-facing units (-1 pads when fewer qualify).

    Forward-facing: the unit is ahead of the ego (positive longitudinal offset, allowing 10 m
    behind) and its optical axis points back toward the ego's side (angle to the ego < 100 deg).
    Best: units whose view (``VIEW_HALF_ANGLE`` either side of the axis, within range) holds the
    point ``LOOKAHEAD_M`` m ahead of the ego come first, smallest ``angle off the axis + distance
    to the point / SELECT_M_PER_RAD`` first; then
    the other forward-facing units, nearest to the ego. Without any, slot 0 is the nearest unit.
    """
    if len(rsus) == 0:
        return np.full(slots, -1, np.int64)
    if HAVE_JIT:
        return select_active_kernel(rsus.pose, float(ego_xy[0]), float(ego_xy[1]), float(ego_yaw),
                                    float(max_range), int(slots), FACING_MAX_ANGLE, LOOKAHEAD_M,
                                    VIEW_HALF_ANGLE)
    d = rsus.pose[:, :2] - ego_xy
    dist = np.linalg.norm(d, axis=1)
    ahead = d @ np.array([np.cos(ego_yaw), np.sin(ego_yaw)]) > -10.0
    to_ego = libm.arctan2(-d[:, 1], -d[:, 0])
    facing = np.abs(wrap_angle(to_ego - rsus.pose[:, 3])) < FACING_MAX_ANGLE
    ok = ahead & facing & (dist < max_range)
    q = ego_xy + LOOKAHEAD_M * np.array([np.cos(ego_yaw), np.sin(ego_yaw)]) - rsus.pose[:, :2]
    dq = row_norms(q)
    off = np.abs(wrap_angle(libm.arctan2(q[:, 1], q[:, 0]) - rsus.pose[:, 3]))
    sees = (dq < max_range) & (off < VIEW_HALF_ANGLE)
    key = np.where(sees, off + dq / SELECT_M_PER_RAD, UNSEEN_KEY + dist)
    order = np.argsort(np.where(ok, key, np.inf), kind="stable")
    out = np.where(ok[order][:slots], order[:slots], -1)
    if out[0] < 0:  # nothing forward-facing: fall back to the nearest unit
        out[0] = int(np.argmin(dist))
    if len(out) < slots:
        out = np.concatenate([out, np.full(slots - len(out), -1, out.dtype)])
    return out.astype(np.int64)
