"""Traffic flows: dense actor flows the ego must enter, cross or merge into at junctions and
on-ramps, slow-traffic merges (CARLA Leaderboard 2.0 names), and the helpers shared with
``junctions.py`` and ``highway.py`` (:class:`Flow`, :class:`FlowScenario`, site finders, timing).

Every class here registers itself with ``@register_scenario``.
"""

from __future__ import annotations

import numpy as np

from ..core.actors import DRIVER, draw_size
from ..core.classes import BICYCLE, CAR, LARGE_VEHICLE
from ..core.geometry import box_corners_2d, world_to_local_2d, wrap_angle
from ..town.model import CONNECTOR, LEFT, PRIORITY, RAMP, RIGHT, STRAIGHT, Town
from ..traffic.jit_vehicles import CORRIDOR_MARGIN_M
from ..traffic.vehicles import LANE_CHANGE_RATE
from .base import Scenario, Site
from .placement import clear_lanes, clear_near, lane_point, spawn_driver
from .registry import register_scenario

FAR = np.array([-1.0e4, -1.0e4])  # where unused rows wait (far from every town)
DODGE_AFTER_S = 4.0  # s a flow vehicle waits for the ego blocking it before steering around it
#: m a dodging flow vehicle keeps between its side and the ego's box: more than the car-following
#: corridor's margin (``jit.CORRIDOR_MARGIN_M``), else the ego stays its leader and it never
#: drives on (with 0.3 m it stood beside the ego for good: tests/scenarios/test_scenarios_flows.py)
DODGE_CLEARANCE_M = CORRIDOR_MARGIN_M + 0.2


# ---------------------------------------------------------------------------- geometry helpers
def park(t, row: int) -> None:
    """Take a scenario row out of the world (inactive, far away, at rest)."""
    t.active[row], t.speed[row], t.hold[row] = False, 0.0, False
    t.pos[row], t.lane[row] = FAR, -1


def end_heading(town: Town, lane: int) -> float:
    """Heading (rad) of a lane at its end."""
    p = town.lanes[lane].points
    return float(np.arctan2(*(p[-1] - p[-2])[::-1]))


def side_of(town: Town, ego_lane: int, other_lane: int) -> str:
    """Where ``other_lane``'s traffic comes from, seen by a driver at the end of ``ego_lane``:
    ``"left"``, ``"right"``, ``"opposite"`` or ``"same"``."""
    d = float(wrap_angle(end_heading(town, other_lane) - end_heading(town, ego_lane)))
    if abs(d) < np.pi / 4:
        return "same"
    if abs(d) > 3 * np.pi / 4:
        return "opposite"
    return "left" if d < 0 else "right"


def connectors(
    town: Town, lane: int, turns: tuple[int, ...] = (LEFT, RIGHT, STRAIGHT)
) -> list[int]:
    """Junction connectors leaving ``lane`` with one of ``turns``."""
    return [
        c
        for c in town.lanes[lane].successors
        if town.lanes[c].kind == CONNECTOR and town.lanes[c].turn in turns
    ]


def same_dir(town: Town, lane: int) -> list[int]:
    """``lane`` and its same-direction neighbours."""
    out, ln = [lane], town.lanes[lane]
    for step in ("left", "right"):
        k = getattr(ln, step)
        while k >= 0:
            out.append(k)
            k = getattr(town.lanes[k], step)
    return out


def first_conflict(
    town: Town, a: int, b: int, clearance: float = 1.5
) -> tuple[float, float] | None:
    """First arc length on lane ``a`` within ``clearance`` m of lane ``b``, and the matching arc
    length on ``b``; ``None`` if they never come that close."""
    ix = town.index
    sa = np.arange(0.0, ix.length[a], 0.5)
    sb = np.arange(0.0, ix.length[b], 0.5)
    pa, _ = ix.pose_at(np.full(len(sa), a), sa)
    pb, _ = ix.pose_at(np.full(len(sb), b), sb)
    d = np.linalg.norm(pa[:, None] - pb[None], axis=-1)
    hit = np.flatnonzero(d.min(1) < clearance)
    if len(hit) == 0:
        return None
    k = int(hit[0])
    return float(sa[k]), float(sb[int(np.argmin(d[k]))])


def ego_eta(sc: Scenario, world, s_target: float, v_min: float = 0.5) -> float:
    """Seconds until the ego reaches route arc length ``s_target`` at its current speed."""
    return max(s_target - sc.ego_s(world), 0.0) / max(float(world.table.speed[0]), v_min)


def set_speed(world, row: int, v: float) -> None:
    """Make a lane follower drive at ``v`` m/s from now on (its IDM desired speed too)."""
    t = world.table
    t.speed[row] = v
    t.v0[row] = v / max(float(world.town.index.speed_limit[t.lane[row]]), 0.1)


def green_for(world, lane: int, seconds: float) -> bool:
    """Whether ``lane``'s light is green now and stays green for ``seconds``."""
    now = world.tick * world.config.dt
    return all(
        world.signals.lane_states(now + dt)[lane] == 0 for dt in np.arange(0.0, seconds + 0.01, 0.5)
    )


def resolve_extra(scenario: Scenario, town) -> tuple:
    """``site.extra`` of a scenario, recomputed from its lanes when the site came from a route file
    (route files store only lanes, key and ``s_on_key``)."""
    if scenario.site.extra:
        return scenario.site.extra
    for s in type(scenario).find_sites(town):
        if s.lanes == scenario.site.lanes and s.key == scenario.site.key:
            return s.extra
    raise ValueError(
        f"scenario {scenario.name}: site {scenario.site.lanes} is not a valid site in {town.name}"
    )


# ---------------------------------------------------------------------------- actor flow
class Flow:
    """A stream of lane-following vehicles (as CARLA's ``ActorFlow``) on a fixed lane path.

    Vehicles enter at path arc length ``start_s`` whenever the last one is a random ``spacing``
    m ahead, drive at ``speed`` m/s (IDM: they brake for whatever is in their corridor, the ego
    included) and leave at ``end_s``. The flow is populated at reset so it is dense from the start.

    Args:
        world: the world (its rows and plans are used).
        path: lane ids from source to sink.
        rows: table rows the flow may use.
        speed: desired speed (m/s).
        spacing: ``(min, max)`` gap between consecutive spawns (m, centre to centre).
        start_s, end_s: source and sink arc lengths on the path (m).
        ignore_rules: the vehicles ignore lights, stop signs and junction yielding (they have the
            right of way, as flows with a frozen green light in CARLA).
        conflict_xy: ``(2,)`` where the flow meets the ego's path (for tests and timing).
        large_fraction: share of trucks / vans among its vehicles.
    """

    def __init__(
        self,
        world,
        path,
        rows,
        speed: float,
        spacing: tuple[float, float],
        start_s: float = 0.0,
        end_s: float | None = None,
        ignore_rules: bool = True,
        conflict_xy=None,
        large_fraction: float = 0.15,
    ) -> None:
        ix, t = world.town.index, world.table
        self.path = [int(x) for x in path]
        self.cum = np.concatenate([[0.0], np.cumsum(ix.length[self.path])])
        self._cum = self.cum.tolist()
        self.start_s = float(max(start_s, 0.0))
        self.end_s = float(min(end_s if end_s is not None else np.inf, self.cum[-1] - 1.0))
        self.rows = np.asarray(rows, np.int64)
        self.speed, self.spacing, self.ignore_rules = float(speed), spacing, ignore_rules
        self.conflict_xy = None if conflict_xy is None else np.asarray(conflict_xy, float)
        world.plans.append(list(self.path))
        self.plan = len(world.plans) - 1
        rng = world.rng
        for r in self.rows:  # sizes are fixed per row for the whole episode (collision shapes)
            kind = LARGE_VEHICLE if rng.random() < large_fraction else CAR
            t.kind[r] = kind
            t.length[r], t.width[r], t.height[r] = draw_size(kind, rng)
            t.behaviour[r] = DRIVER
            park(t, r)
        self._gap = float(rng.uniform(*spacing))
        self.dodge: dict[int, float] = {}  # row -> lateral offset while steering around the ego

    def _dodge(self, world, r: int) -> None:
        """A vehicle stopped for a while by the ego standing in its way steers around it (the
        ego's own driver may be waiting for that very vehicle: a deadlock otherwise)."""
        t = world.table
        rel = world_to_local_2d(t.pos[0], t.pos[r], float(t.yaw[r]))
        reach = 0.5 * (t.length[0] + t.length[r]) + 1.0
        if r in self.dodge:
            if rel[0] < -reach:
                del self.dodge[r]
            else:
                step = LANE_CHANGE_RATE * world.config.dt
                # ease sideways, and cancel the engine's decay of ``lat`` back to the lane centre
                lat = float(np.clip(self.dodge[r], t.lat[r] - step, t.lat[r] + step))
                t.lat[r] = lat + np.sign(lat) * step
                t.yaw[r] = float(world.town.index.pose_at(t.lane[r : r + 1], t.s[r : r + 1])[1][0])
            return
        if t.wait[r] > DODGE_AFTER_S and 0.0 < rel[0] < reach + 8.0:
            ego = box_corners_2d(t.pos[:1], t.length[:1], t.width[:1], t.yaw[:1])[0]
            y = world_to_local_2d(ego, t.pos[r], float(t.yaw[r]))[:, 1]
            half = 0.5 * t.width[r] + DODGE_CLEARANCE_M
            if y.min() < half and y.max() > -half:  # the ego's box overlaps its corridor
                c = min((y.min() - half, y.max() + half), key=abs)
                self.dodge[r] = float(np.clip(c, -3.0, 3.0))

    def path_s(self, t) -> np.ndarray:
        """Path arc length of each flow row (``nan`` where inactive)."""
        return np.array(self._path_s(t, t.active[self.rows].tolist()))

    def _path_s(self, t, active: list) -> list[float]:
        """:meth:`path_s` as Python floats, given ``t.active`` of the rows (a few rows: Python
        numbers cost less than NumPy's calls; the sums are the same floats)."""
        rows, last, cum = self.rows, len(self.path) - 1, self._cum
        out = []
        for a, plan, k, s in zip(active, t.plan[rows].tolist(), t.plan_pos[rows].tolist(), t.s[rows].tolist()):
            out.append(cum[min(max(k, 0), last)] + s if a and plan == self.plan else np.nan)
        return out

    def place(self, world, row: int, s: float, speed: float) -> None:
        """Put flow row ``row`` at path arc length ``s`` driving at ``speed``."""
        t = world.table
        k = int(np.clip(np.searchsorted(self.cum, s, side="right") - 1, 0, len(self.path) - 1))
        spawn_driver(
            world,
            int(row),
            self.path[k],
            s - self.cum[k],
            kind=int(t.kind[row]),
            speed=speed,
            ignore_rules=self.ignore_rules,
            size=(t.length[row], t.width[row], t.height[row]),
        )
        t.plan[row], t.plan_pos[row] = self.plan, k
        set_speed(world, int(row), speed)

    def point(self, town: Town, s: float) -> tuple[np.ndarray, float]:
        """Position (m) and heading (rad) at path arc length ``s``."""
        k = int(np.clip(np.searchsorted(self.cum, s, side="right") - 1, 0, len(self.path) - 1))
        return lane_point(town, self.path[k], s - self.cum[k])

    def _free(self, world, s: float, radius: float) -> bool:
        """No vehicle in the lane within ``radius`` m of path arc length ``s`` (parked cars and
        traffic in other lanes do not count)."""
        t = world.table
        p, h = self.point(world.town, s)
        local = world_to_local_2d(t.pos, p, h)
        vehicles = t.active & np.isin(t.kind, (CAR, LARGE_VEHICLE, BICYCLE))
        inside = (np.abs(local[:, 0]) < radius) & (np.abs(local[:, 1]) < 2.5)
        return not np.any(vehicles & inside)

    def populate(self, world) -> None:
        """Fill the path from sink to source with vehicles ``spacing`` apart."""
        rng = world.rng
        s = self.end_s - rng.uniform(0.0, self.spacing[0])
        for r in self.rows:
            while s > self.start_s + 5.0 and not self._free(world, s, 10.0):
                s -= 5.0
            if s <= self.start_s + 5.0:
                break
            self.place(world, r, s, self.speed)
            s -= rng.uniform(*self.spacing)

    def step(self, world) -> None:
        """Keep speeds, retire vehicles past the sink, spawn at the source, break deadlocks."""
        t, ix = world.table, world.town.index
        rows = self.rows
        # per-row values as Python numbers: a few rows, where NumPy's per-call cost dominates
        active, lanes, wait = t.active[rows].tolist(), t.lane[rows].tolist(), t.wait[rows].tolist()
        s = self._path_s(t, active)  # nan where inactive
        free, ahead = [], []
        for k, r in enumerate(rows.tolist()):
            if not active[k] or s[k] > self.end_s:
                if active[k] or t.pos[r, 0] != FAR[0]:
                    park(t, r)
                self.dodge.pop(r, None)
                free.append(r)  # inactive now
                continue
            if s[k] == s[k]:  # path_s after the parking above: rows only touch their own columns
                ahead.append(s[k] - self.start_s)
            turning = ix.turn[lanes[k]] in (LEFT, RIGHT)
            t.v0[r] = 1.0 if turning else self.speed / ix.speed_limit[lanes[k]]
            if r in self.dodge or wait[k] > DODGE_AFTER_S:
                self._dodge(world, r)
        if free and (not ahead or min(ahead) >= self._gap) and self._free(world, self.start_s, 8.0):
            self.place(world, free[0], self.start_s, self.speed)
            self._gap = float(world.rng.uniform(*self.spacing))


class FlowScenario(Scenario):
    """Base of the actor-flow scenarios: ``site.extra`` holds ``(path, conflict_s_on_path)`` per
    flow; rows are shared out between the flows. Parameters: ``speed`` (m/s) of the flow,
    ``spacing_min`` / ``spacing_max`` (m) between its vehicles, per carriageway (flows in
    parallel lanes of one approach share them, see :meth:`spacing`). Crossing and merging flows
    are dense on average but their spacings reach ~6-7 s, so that a gap a careful driver accepts
    comes every few vehicles (with tighter flows the rule expert waited out the scenario
    timeout)."""

    family = "flow"
    max_actors = 16
    timeout_s = 90.0
    upstream = 120.0  # m of flow before its conflict point
    downstream = 35.0  # m of flow after it
    ignore_rules = True
    defaults = {"speed": 10.0, "spacing_min": 25.0, "spacing_max": 70.0}

    def spawn(self, world) -> None:
        flows = self.flow_paths(world.town)
        all_rows = self.flow_rows()
        n = len(flows)
        per = len(all_rows) // n
        self.flows: list[Flow] = []
        lanes = []
        for k, (path, s_conf) in enumerate(flows):
            rows = all_rows[k * per : (k + 1) * per]
            v = self.flow_speed()
            lo, hi = s_conf - self.upstream, s_conf + self.downstream
            f = Flow(world, path, rows, v, self.spacing(world.town, flows, k), lo, hi, self.ignore_rules)
            f.conflict_xy = f.point(world.town, s_conf)[0]
            self.flows.append(f)
            lanes += list(path)
        clear_lanes(world, lanes + self.approach())
        clear_near(world, self.conflict_point, 15.0)
        for f in self.flows:
            f.populate(world)
        self.hazard_rows = [int(r) for f in self.flows for r in f.rows]

    def flow_paths(self, town: Town) -> tuple:
        """``(path, conflict_s_on_path)`` per flow: ``site.extra`` (:func:`resolve_extra`)."""
        return resolve_extra(self, town)

    def flow_rows(self) -> np.ndarray:
        """Rows the flows share: all of the scenario's (subclasses keep some for other actors)."""
        return self.rows

    def flow_speed(self) -> float:
        """Desired speed (m/s) of the flows' vehicles: ``params["speed"]``."""
        return float(self.params["speed"])

    def spacing(self, town: Town, flows: list, k: int) -> tuple[float, float]:
        """``(min, max)`` spacing (m) of flow ``k``: the parameters are per carriageway, so flows
        in parallel lanes of one approach share them (each lane's spacing times the lane count);
        otherwise a two-lane flow leaves a gap in both lanes at once far more rarely than a
        one-lane flow, and the expert waited out the scenario timeout."""
        parallel = set(same_dir(town, flows[k][0][0]))
        share = sum(path[0] in parallel for path, _ in flows)
        return (share * float(self.params["spacing_min"]), share * float(self.params["spacing_max"]))

    def approach(self) -> list[int]:
        """The ego's lanes up to the conflict: background traffic waiting there for a gap in the
        flow would block the ego (CARLA clears the ego's junction entry too)."""
        return list(self.site.lanes[: self.site.key + 1])

    def on_trigger(self, world) -> None:
        clear_lanes(world, self.approach())

    def tick(self, world) -> None:
        for f in self.flows:
            f.step(world)
        super().tick(world)


def merge_sites(
    town: Town,
    turn: int,
    controls: tuple[int, ...] = (PRIORITY,),
    minor: bool = True,
    from_side: str | None = None,
) -> list[Site]:
    """Sites where the ego turns (``turn``) into a lane that carries a straight-through flow.

    The ego's incoming lane is a minor (stop) lane when ``minor``; flows come from major approaches
    (``from_side`` filters them) and run straight into the very lane the ego joins (on multi-lane
    roads the other lanes keep their background traffic). The conflict point is where the ego's
    connector first comes within 1.5 m of the flow's.
    """
    sites = []
    for j in town.junctions:
        if j.control not in controls:
            continue
        for e in j.incoming:
            if (e in j.stop_lanes) != minor or town.index.length[e] < 30:
                continue
            for c in connectors(town, e, (turn,)):
                out = town.lanes[c].successors[0]
                if town.index.length[out] < 30:
                    continue
                flows, hits = [], []
                for a in j.incoming:
                    if a == e or (a in j.stop_lanes and j.control == PRIORITY):
                        continue
                    if from_side and side_of(town, e, a) != from_side:
                        continue
                    for f in connectors(town, a, (STRAIGHT,)):
                        hit = first_conflict(town, c, f)
                        if town.lanes[f].successors[0] == out and hit is not None:
                            flows.append(((a, f, out), float(town.index.length[a] + hit[1])))
                            hits.append(hit[0])
                if flows:
                    sites.append(Site((e, c, out), 1, min(hits), tuple(flows)))
    return sites


def ramp_sites(town: Town, ego_on_ramp: bool) -> list[Site]:
    """Highway on-ramp merges: ``(ramp, connector, highway lane)`` for the ramp driver, the
    highway's outer lane for the other; ``extra`` holds the other party's path."""
    sites = []
    for ramp in (ln for ln in town.lanes if ln.kind == RAMP):
        for cr in connectors(town, ramp.id):
            out = town.lanes[cr].successors[0]
            for ch in town.lanes[out].predecessors:
                if ch == cr or town.lanes[ch].kind != CONNECTOR or not town.lanes[ch].predecessors:
                    continue
                e = town.lanes[ch].predecessors[0]
                hit = first_conflict(town, cr, ch, clearance=2.2)
                if hit is None:
                    continue
                mine, other = (
                    ((ramp.id, cr, out), (e, ch, out))
                    if ego_on_ramp
                    else ((e, ch, out), (ramp.id, cr, out))
                )
                s_me, s_other = hit if ego_on_ramp else hit[::-1]
                s_path = float(town.index.length[other[0]] + s_other)
                sites.append(Site(mine, 1, s_me, ((other, s_path),)))
    return sites


# ---------------------------------------------------------------------------- flow scenarios
@register_scenario
class EnterActorFlow(FlowScenario):
    """The ego leaves a minor (stop) road at a priority junction turning right into a major road
    with a dense flow of vehicles coming from its left; it must find a gap in the flow.

    The flow (IDM vehicles with the right of way) runs from reset on and keeps running, so
    vehicles pass the merge point every few seconds whenever the ego arrives.

    Parameters: ``speed`` (m/s) of the flow; ``spacing_min`` / ``spacing_max`` (m) between its
    vehicles (centre to centre).
    """

    name = "EnterActorFlow"
    towns = ("Town06", "Town02", "Town01", "Town05")

    @classmethod
    def find_sites(cls, town):
        return merge_sites(town, RIGHT, from_side="left")


@register_scenario
class EnterActorFlowV2(FlowScenario):
    """Variant of EnterActorFlow: the ego enters a highway from an on-ramp while a dense flow
    drives in the lane it merges into (as CARLA's highway-entry version). In towns without a
    highway the ego instead turns left out of a minor road into the far lanes of a major road,
    whose flow comes from its right.

    Parameters: ``speed`` (m/s) of the flow; ``spacing_min`` / ``spacing_max`` (m).
    """

    name = "EnterActorFlowV2"
    towns = ("Town04", "Town06", "Town01")
    defaults = {"speed": 14.0, "spacing_min": 30.0, "spacing_max": 90.0}

    @classmethod
    def find_sites(cls, town):
        return ramp_sites(town, ego_on_ramp=True) or merge_sites(town, LEFT, from_side="right")


@register_scenario
class MergerIntoSlowTraffic(FlowScenario):
    """The ego merges into slow, dense traffic: on a highway it comes down the on-ramp into a
    congested outer lane; in towns without a highway it turns right out of a minor road into a
    slow queue on the major road.

    Parameters: ``speed`` (m/s) of the queue; ``spacing_min`` / ``spacing_max`` (m).
    """

    name = "MergerIntoSlowTraffic"
    towns = ("Town04", "Town06", "Town02", "Town01")
    upstream = 90.0
    defaults = {"speed": 4.0, "spacing_min": 12.0, "spacing_max": 30.0}

    @classmethod
    def find_sites(cls, town):
        return ramp_sites(town, ego_on_ramp=True) or merge_sites(town, RIGHT, from_side="left")


@register_scenario
class MergerIntoSlowTrafficV2(FlowScenario):
    """Variant of MergerIntoSlowTraffic at a junction exit: the ego turns left out of a minor
    road into the far lanes of a major road, joining a slow, dense queue that comes from its right.

    Parameters: ``speed`` (m/s) of the queue; ``spacing_min`` / ``spacing_max`` (m).
    """

    name = "MergerIntoSlowTrafficV2"
    towns = ("Town06", "Town02", "Town01", "Town05")
    upstream = 90.0
    defaults = {"speed": 4.0, "spacing_min": 12.0, "spacing_max": 30.0}

    @classmethod
    def find_sites(cls, town):
        return merge_sites(town, LEFT, from_side="right")


def crossing_sites(
    town: Town,
    controls: tuple[int, ...],
    ego_turns: tuple[int, ...],
    minor: bool | None,
    sides: tuple[str, ...],
    flow_turns: tuple[int, ...] = (STRAIGHT,),
    flow_minor: bool | None = None,
) -> list[Site]:
    """Sites where the ego's connector crosses other approaches' connectors.

    ``minor``: the ego's lane is (``True``) / is not (``False``) a stop lane (``None``: any);
    ``sides``: approaches the crossing traffic comes from (``side_of``); ``flow_minor`` as
    ``minor`` for the crossing approach. ``extra`` holds ``(path, conflict_s_on_path)`` for every
    crossing connector; the conflict point is the first crossing on the ego's connector.
    """
    sites = []
    for j in town.junctions:
        if j.control not in controls:
            continue
        for e in j.incoming:
            if minor is not None and (e in j.stop_lanes) != minor:
                continue
            if town.index.length[e] < 30:
                continue
            for c in connectors(town, e, ego_turns):
                out = town.lanes[c].successors[0]
                flows, hits = [], []
                for a in j.incoming:
                    if a == e or side_of(town, e, a) not in sides:
                        continue
                    if flow_minor is not None and (a in j.stop_lanes) != flow_minor:
                        continue
                    for f in connectors(town, a, flow_turns):
                        hit = first_conflict(town, c, f)
                        nxt = town.lanes[f].successors[0]
                        if hit is None or nxt in same_dir(town, out) or town.index.length[nxt] < 25:
                            continue
                        flows.append(((a, f, nxt), float(town.index.length[a] + hit[1])))
                        hits.append(hit[0])
                if flows and town.index.length[out] >= 25:
                    sites.append(Site((e, c, out), 1, min(hits), tuple(flows)))
    return sites


@register_scenario
class InterurbanActorFlow(FlowScenario):
    """The ego leaves a major road by turning left at a priority junction, across a dense flow of
    oncoming vehicles that have the right of way; it must wait for a gap.

    Parameters: ``speed`` (m/s) of the oncoming flow; ``spacing_min`` / ``spacing_max`` (m).
    """

    name = "InterurbanActorFlow"
    towns = ("Town06", "Town02", "Town01", "Town05")
    defaults = {"speed": 11.0, "spacing_min": 25.0, "spacing_max": 75.0}

    @classmethod
    def find_sites(cls, town):
        return crossing_sites(
            town, (PRIORITY,), (LEFT,), minor=False, sides=("opposite",), flow_minor=False
        )


@register_scenario
class InterurbanAdvancedActorFlow(FlowScenario):
    """The ego leaves a minor road by turning left onto a major road with flows in both
    directions: it first crosses the flow coming from its left, then merges into the flow coming
    from its right.

    Parameters: ``speed`` (m/s) of both flows; ``spacing_min`` / ``spacing_max`` (m).
    """

    name = "InterurbanAdvancedActorFlow"
    towns = ("Town06", "Town02", "Town01", "Town05")
    defaults = {"speed": 10.0, "spacing_min": 25.0, "spacing_max": 70.0}

    @classmethod
    def find_sites(cls, town):
        sites = []
        merges = {(s.lanes, s.key): s for s in merge_sites(town, LEFT, from_side="right")}
        for s in crossing_sites(
            town, (PRIORITY,), (LEFT,), minor=True, sides=("left",), flow_minor=False
        ):
            m = merges.get((s.lanes, s.key))
            if m is not None:
                sites.append(Site(s.lanes, 1, s.s_on_key, (s.extra[0], m.extra[0])))
        return sites
