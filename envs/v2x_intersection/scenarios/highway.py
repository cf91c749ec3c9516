"""Highway and emergency scenarios: exiting across a flow, a cut-in from the on-ramp, and an
emergency vehicle that needs the ego to make way (CARLA Leaderboard 2.0 names). Built on the
helpers of ``flows.py``.

The highway types need ramps: Town04 (highway section) and the held-out test town Town12 (a grid
city with a highway joined by an off- and an on-ramp) host them.

Every class here registers itself with ``@register_scenario``.
"""

from __future__ import annotations

import numpy as np

from ..core.classes import LARGE_VEHICLE
from ..core.dynamics import IDMParams, idm_accel
from ..core.geometry import world_to_local_2d
from ..evaluation.infractions import YIELD_EMERGENCY
from ..town.model import CONNECTOR, RAMP, STRAIGHT
from ..town.routes import LANE_CHANGE_LENGTH
from ..traffic.signals import RED, YELLOW
from .base import Scenario, Site
from .flows import (
    Flow,
    FlowScenario,
    connectors,
    ego_eta,
    park,
    ramp_sites,
    resolve_extra,
    set_speed,
)
from .placement import clear_lanes, spawn_scripted, straight_sites
from .registry import register_scenario


@register_scenario
class HighwayExit(FlowScenario):
    """The ego must leave the highway by the off-ramp: it changes from the middle into the outer
    lane, crossing a fast flow of vehicles driving in the outer lane that stays on the highway,
    then takes the exit.

    It needs an off-ramp: Town04, and the highway of the held-out town Town12.

    Parameters: ``speed`` (m/s) of the flow; ``spacing_min`` / ``spacing_max`` (m).
    """

    name = "HighwayExit"
    family = "highway"
    towns = ("Town04",)
    upstream = 200.0
    downstream = 60.0
    ignore_rules = False
    defaults = {"speed": 15.0, "spacing_min": 25.0, "spacing_max": 45.0}

    def __init__(self, route, site, conflict_s, params=None) -> None:
        super().__init__(route, site, conflict_s, params)
        on_ramp = np.flatnonzero(route.lane_ids == site.lanes[-1])
        if len(on_ramp):  # passed once on the off-ramp, as CARLA's WaitEndIntersection
            self.end_s = min(float(route.s[on_ramp[0]]) + 5.0, route.length - 1.0)

    @classmethod
    def find_sites(cls, town):
        sites = []
        for ln in town.lanes:
            if ln.kind == RAMP or ln.right < 0 or ln.length < 100:
                continue
            r = town.lanes[ln.right]
            exits = [
                c
                for c in connectors(town, r.id)
                if town.lanes[town.lanes[c].successors[0]].kind == RAMP
            ]
            stay = [c for c in connectors(town, r.id, (STRAIGHT,)) if c not in exits]
            if exits and stay:
                ramp = town.lanes[exits[0]].successors[0]
                # routes blend a lane change over LANE_CHANGE_LENGTH m in the middle of the lane;
                # the conflict is half-way through it (s_on_key counts from the blend start)
                half = 0.5 * LANE_CHANGE_LENGTH
                blend = 0.5 * (ln.length - LANE_CHANGE_LENGTH)
                flow = ((r.id, stay[0], town.lanes[stay[0]].successors[0]), float(blend + half))
                sites.append(Site((ln.id, r.id, exits[0], ramp), 1, half, (flow,)))
        return sites


# ---------------------------------------------------------------------------- highway cut-in
@register_scenario
class HighwayCutIn(Scenario):
    """On the highway, a vehicle coming up the on-ramp merges into the ego's (outer) lane just in
    front of it.

    At the trigger the vehicle appears on the ramp; its speed is then synchronised (as CARLA's
    ``SyncArrival``) so that it reaches the merge point ``lead`` seconds before the ego, after which
    it keeps ``speed_after`` m/s in the ego's lane. It needs an on-ramp: Town04, and the highway
    of the held-out town Town12.

    Parameters: ``lead`` (s) ahead of the ego at the merge; ``ramp_speed`` (m/s) nominal speed on
    the ramp; ``speed_after`` (m/s) after merging.
    """

    name = "HighwayCutIn"
    family = "highway"
    max_actors = 1
    towns = ("Town04",)
    trigger_distance = 80.0
    defaults = {"lead": 1.0, "ramp_speed": 14.0, "speed_after": 10.0}

    @classmethod
    def find_sites(cls, town):
        return ramp_sites(town, ego_on_ramp=False)

    def spawn(self, world) -> None:
        ((path, s_conf),) = resolve_extra(self, world.town)
        row = int(self.rows[0])
        v = float(self.params["ramp_speed"])
        self.flow = Flow(world, path, [row], v, (1e3, 1e3), 0.0, None, True, large_fraction=0.0)
        self.s_merge = s_conf
        clear_lanes(world, list(path))
        self.hazard_rows = [row]

    def on_trigger(self, world) -> None:
        lead, v_nom = float(self.params["lead"]), float(self.params["ramp_speed"])
        d0 = v_nom * (ego_eta(self, world, self.conflict_s) - lead)  # on the ramp at nominal speed
        d0 = float(np.clip(d0, 20.0, self.s_merge - 2.0))
        self.flow.place(world, int(self.rows[0]), self.s_merge - d0, v_nom)

    def update(self, world) -> None:
        t, row = world.table, int(self.rows[0])
        if not t.active[row]:
            return
        s = float(self.flow.path_s(t)[0])
        if s < self.s_merge:
            eta = ego_eta(self, world, self.conflict_s) - float(self.params["lead"])
            v_des = float(np.clip((self.s_merge - s) / max(eta, 0.3), 5.0, 28.0))
            dv = np.clip(v_des - t.speed[row], -4.0 * world.config.dt, 3.0 * world.config.dt)
            set_speed(world, row, float(t.speed[row] + dv))
        else:
            limit = world.town.index.speed_limit[t.lane[row]]
            t.v0[row] = float(self.params["speed_after"]) / limit


# ---------------------------------------------------------------------------- emergency vehicle
#: an emergency driver tailgates whatever is in its way
EV_IDM = IDMParams(time_headway=0.6, min_gap=4.0, accel=2.5, decel=4.0)


@register_scenario
class YieldToEmergencyVehicle(Scenario):
    """An emergency vehicle (ambulance-sized, listed in ``emergency_rows``) approaches fast from
    behind in the ego's lane on a multi-lane road; the ego must let it pass by changing lane (or
    moving well aside).

    The emergency vehicle appears ``distance`` m behind the ego at the trigger and drives along the
    ego's route (scripted): it ignores lights and signs, never overtakes by itself and follows
    whatever blocks the route ahead with a short (0.6 s) headway.

    Failure: when it stays stuck behind the ego (bumper gap under ``stuck_distance`` m, slower than
    80% of its desired speed) for more than ``stuck_time`` s while the ego could yield (not
    waiting at a red light, not inside a junction), a ``YIELD_EMERGENCY`` event is emitted once.

    Parameters: ``speed`` (m/s) the emergency vehicle wants; ``distance`` (m) behind the ego where
    it appears; ``stuck_distance`` (m); ``stuck_time`` (s).
    """

    name = "YieldToEmergencyVehicle"
    lanes_free = True  # changing lane to let it pass is the manoeuvre
    family = "emergency"
    max_actors = 1
    towns = ("Town04", "Town03", "Town01")
    trigger_distance = 30.0
    defaults = {"speed": 20.0, "distance": 45.0, "stuck_distance": 15.0, "stuck_time": 10.0}

    def __init__(self, route, site, conflict_s, params=None) -> None:
        super().__init__(route, site, conflict_s, params)
        self.end_s = min(self.conflict_s + 120.0, route.length - 1.0)
        self.emergency_rows: list[int] = []
        self.stuck_s = 0.0
        self.emitted = False
        self.s_ev = self.v_ev = 0.0

    @classmethod
    def find_sites(cls, town):
        return [
            s
            for s in straight_sites(town, min_length=60.0, multi_lane=True)
            if town.lanes[s.lanes[0]].kind != RAMP
        ]

    def spawn(self, world) -> None:
        row = int(self.rows[0])
        spawn_scripted(world, row, LARGE_VEHICLE, self.route.points[0], 0.0, size=(6.4, 2.3, 2.8))
        park(world.table, row)
        self.emergency_rows = self.hazard_rows = [row]

    def _pose(self, s: float) -> tuple[np.ndarray, float]:
        r = self.route
        p = np.array([np.interp(s, r.s, r.points[:, 0]), np.interp(s, r.s, r.points[:, 1])])
        return p, float(r.headings[min(int(np.searchsorted(r.s, s)), len(r.s) - 1)])

    def on_trigger(self, world) -> None:
        t, row = world.table, self.emergency_rows[0]
        self.s_ev = max(self.ego_s(world) - float(self.params["distance"]), 0.0)
        self.v_ev = min(float(self.params["speed"]), 15.0)
        k0, k1 = np.searchsorted(self.route.s, [self.s_ev, self.ego_s(world)])
        clear_lanes(world, sorted(set(self.route.lane_ids[k0 : k1 + 1].tolist())))
        p, h = self._pose(self.s_ev)
        t.active[row], t.pos[row], t.yaw[row], t.speed[row] = True, p, h, self.v_ev

    def _leader(self, world) -> tuple[float, float]:
        """Bumper gap (m) and speed along the route of the nearest actor on the route ahead."""
        t, r, row = world.table, self.route, self.emergency_rows[0]
        near = np.flatnonzero(t.active & (np.linalg.norm(t.pos - t.pos[row], axis=1) < 60.0))
        near = near[near != row]
        k0 = int(np.searchsorted(r.s, self.s_ev))
        seg = slice(k0, min(k0 + 70, len(r.s)))
        if len(near) == 0 or seg.start >= len(r.s):
            return np.inf, 0.0
        d = np.linalg.norm(t.pos[near][:, None] - r.points[seg][None], axis=-1)
        j = np.argmin(d, axis=1)
        ok = d[np.arange(len(near)), j] < 0.5 * (t.width[row] + t.width[near]) + 0.3
        ok &= r.s[seg][j] > self.s_ev
        if not np.any(ok):
            return np.inf, 0.0
        gaps = r.s[seg][j] - self.s_ev - 0.5 * (t.length[row] + t.length[near])
        gaps = np.where(ok, gaps, np.inf)
        k = int(np.argmin(gaps))
        v_lead = t.speed[near[k]] * max(np.cos(t.yaw[near[k]] - r.headings[seg][j[k]]), 0.0)
        return float(gaps[k]), float(v_lead)

    def update(self, world) -> None:
        t, dt, row = world.table, world.config.dt, self.emergency_rows[0]
        if not t.active[row]:
            return
        want = float(self.params["speed"])
        gap, v_lead = self._leader(world)
        v, f64 = self.v_ev, np.float64
        acc = float(idm_accel(f64(v), f64(want), f64(gap), f64(v - v_lead), EV_IDM))
        self.v_ev = max(self.v_ev + acc * dt, 0.0)
        self.s_ev += self.v_ev * dt
        if self.s_ev >= self.route.length - 1.0:
            park(t, row)
            return
        p, h = self._pose(self.s_ev)
        t.pos[row], t.yaw[row], t.speed[row] = p, h, self.v_ev
        rel = world_to_local_2d(t.pos[0], p, h)
        ego_gap = rel[0] - 0.5 * (t.length[0] + t.length[row])
        stuck = 0.0 < ego_gap < float(self.params["stuck_distance"]) and abs(rel[1]) < 1.5
        stuck &= self.v_ev < 0.8 * want
        ego_lane = int(self.route.lane_ids[world.monitor.progress])
        in_junction = world.town.index.kind[ego_lane] == CONNECTOR
        can_yield = not in_junction and world.lane_signal[ego_lane] not in (RED, YELLOW)
        if not stuck:
            self.stuck_s = 0.0
        elif can_yield:
            self.stuck_s += dt
        if self.stuck_s > float(self.params["stuck_time"]) and not self.emitted:
            self.emitted = True
            world.monitor.emit(YIELD_EMERGENCY, world.tick, int(t.actor_id[row]), self.stuck_s)
