"""A PDM-Lite-like rule planner on an object-list abstraction.

Every tick :meth:`Planner.step` takes the ego state, the route (``RouteTrack``), the signal state
of every lane (lights and stop signs are road furniture) and a list of objects in the world frame
(``objects.Objects``), and returns controls plus future waypoints:

1. localize the ego on the route and cut a path window ahead of it;
2. lateral manoeuvres (``lateral``): offsets around static obstacles, room for emergency vehicles;
3. objects in the path frame; the *corridor* is the ego's width plus a margin along the
   (shifted) path; objects in it ahead are IDM leaders;
4. junction rules (``junction``): lights, stop signs, yielding before entering;
5. prediction (``prediction``) over 4 s; every hypothesis that enters the corridor while the
   ego (on its nominal speed profile) would be there is a conflict: crossing or oncoming ones
   become stop points before where they enter, same-direction ones (cut-ins) leaders;
6. acceleration = IDM minimum over all constraints (``longitudinal``); pure-pursuit steering;
7. waypoints: the planned speed profile rolled out along the path, every 0.5 s for 4 s, in the
   ego frame (imitation targets).

The same planner drives the privileged expert (all actors) and the restricted oracles (what the
ego sees, plus what the RSU sent); only the object list differs.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from v2xbench.envs.v2x_intersection.core.classes import BICYCLE, PEDESTRIAN
from v2xbench.envs.v2x_intersection.core.dynamics import VehicleParams
from v2xbench.envs.v2x_intersection.core.geometry import stack_xy, world_to_local_2d
from v2xbench.envs.v2x_intersection.town.model import Town
from v2xbench.envs.v2x_intersection.town.routes import Route

from .junction import JunctionRules, travel_time
from .lanes import lane_map
from .lateral import PASS_ACCEL, LateralPlanner
from .longitudinal import LonParams, accel_now, envelope, rollout
from .objects import Objects
from .prediction import forecast
from .route_track import RouteTrack
from .scalar import clip

N_WAYPOINTS = 8
WAYPOINT_DT = 0.5  # s
ROLL_DT = 0.25  # s, speed-profile integration step
ROLL_STEPS = 16  # 4 s


@dataclass(frozen=True)
class PlannerParams:
    """Planner constants (m, s, m/s)."""

    ego_length: float = 4.7
    ego_width: float = 1.9
    lat_margin: float = 0.35  # corridor margin for vehicles (each side)
    lat_margin_vru: float = 0.8  # for pedestrians and bicycles
    lat_margin_static: float = 0.2  # for standing static objects (cones, barriers, parked cars)
    stop_margin: float = 2.5  # gap kept before a predicted conflict (vehicles)
    stop_margin_vru: float = 3.5
    leader_s0: float = 3.0  # standstill gap behind a vehicle
    static_s0: float = 9.0  # behind a standing obstacle (room to steer around it)
    headway: float = 1.2  # s
    relevance_m: float = 110.0  # objects farther away are ignored
    commit_decel: float = 4.5  # m/s^2: a conflict needing more to stop for may be cleared instead
    clear_buffer: float = 0.8  # s kept when clearing a conflict zone ahead of another actor
    lookahead_min: float = 3.5
    lookahead_gain: float = 0.45  # s
    lookahead_max: float = 12.0


@dataclass
class Plan:
    """One planning step's output.

    Attributes:
        control: ``(3,)`` throttle, steer, brake. accel: commanded acceleration (m/s^2).
        waypoints: ``(N_WAYPOINTS, 2)`` future positions in the ego frame, every ``WAYPOINT_DT`` s.
        speeds: ``(N_WAYPOINTS,)`` planned speeds there (m/s). reason: binding constraint.
        path: ``(P, 2)`` the (shifted) path in the world frame.
    """

    control: np.ndarray
    accel: float
    waypoints: np.ndarray
    speeds: np.ndarray
    reason: str
    path: np.ndarray


class Planner:
    """The rule planner (see module docstring)."""

    def __init__(
        self,
        params: PlannerParams | None = None,
        lon: LonParams | None = None,
        vehicle: VehicleParams | None = None,
    ) -> None:
        self.p = params or PlannerParams()
        self.lon = lon or LonParams()
        self.vehicle = vehicle or VehicleParams()
        self.hl, self.hw = 0.5 * self.p.ego_length, 0.5 * self.p.ego_width
        self.track: RouteTrack | None = None
        #: optional ``f(stations, objs, st, lat, e_long) -> (P,)`` speed caps (m/s) along the path
        #: window's stations, from the objects' stations ``st``, lateral offsets ``lat`` and
        #: half-lengths along the path ``e_long``; ``None``: no extra caps
        self.zone_caps = None

    def reset(self, town: Town, route: Route) -> None:
        """Start a new route."""
        self.town = town
        self.lmap = lane_map(town)
        self.track = RouteTrack(town, route)
        self.junction = JunctionRules(self.track, self.lmap, self.hl)
        self.lateral = LateralPlanner(self.track, self.hl, self.hw)

    # ------------------------------------------------------------------ main step
    def step(
        self, pos: np.ndarray, yaw: float, v: float, objs: Objects, lane_signal: np.ndarray
    ) -> Plan:
        """Plan one tick.

        Args:
            pos: ``(2,)`` ego position (m). yaw: heading (rad). v: speed (m/s).
            objs: objects around the ego (world frame).
            lane_signal: ``(num_lanes,)`` signal state per lane (``signals``).
        """
        if self.track is None:
            raise RuntimeError("Planner.step() before reset(town, route)")
        p, hl = self.p, self.hl
        pos = np.asarray(pos, float)
        j, s_ego = self.track.localize(pos)
        ahead = float(clip(6.0 * v + 40.0, 60.0, 170.0))
        win0 = self.track.window(j, s_ego, ahead)
        d = objs.pos - pos
        objs = objs.take((d[:, 0] ** 2 + d[:, 1] ** 2) < p.relevance_m**2)
        dirs = stack_xy(np.cos(objs.yaw), np.sin(objs.yaw))
        st, lat, _, cr, sr = win0.project(objs.pos, dirs)
        self.lateral.update(s_ego, v, win0, objs, st, lat, cr, sr)
        offs = self.lateral.offsets(s_ego)
        win = win0 if offs is None else self.track.window(j, s_ego, ahead, offs)
        o_obj = np.zeros(len(st)) if offs is None else offs(st)
        vru = (objs.kind == PEDESTRIAN) | (objs.kind == BICYCLE)
        e_lat = np.abs(0.5 * objs.length * sr) + np.abs(0.5 * objs.width * cr)
        e_long = np.abs(0.5 * objs.length * cr) + np.abs(0.5 * objs.width * sr)
        speed = objs.speed
        # leaders in the corridor now
        cons: list[tuple[float, float, float, float]] = []
        reasons: list[str] = []
        margin = np.where(
            vru, p.lat_margin_vru, np.where(objs.static, p.lat_margin_static, p.lat_margin)
        )
        in_corr = np.abs(lat - o_obj) < self.hw + e_lat + margin
        lead = (in_corr & (st - e_long > hl - 1.0) & (st < win.st[-1])).nonzero()[0]
        for i in lead[(st[lead] - e_long[lead]).argsort()][:3]:
            s0 = p.static_s0 if objs.static[i] else p.leader_s0
            cons.append(
                (
                    float(st[i] - e_long[i] - hl),
                    float(clip(speed[i] * cr[i], -5.0, None)),
                    s0,
                    p.headway,
                )
            )
            reasons.append("leader")
        # junction rules
        fc = forecast(objs, self.lmap, lane_signal, ~objs.static)
        for gap, vt, s0, hw, why in self.junction.constraints(s_ego, v, lane_signal, objs, fc):
            cons.append((gap, vt, s0, hw))
            reasons.append(why)
        # speed envelope (limits, curves, manoeuvre caps)
        vlim = np.minimum(win.vlim, self.lateral.speed_cap)
        if self.zone_caps is not None:  # caller's speed zones (e.g. the cautious ego's)
            vlim = np.minimum(vlim, self.zone_caps(win.st, objs, st, lat, e_long))
        man = self.lateral.man
        lon = self.lon if man is None or not man.invades else replace(self.lon, accel=PASS_ACCEL)
        env = envelope(win.st, vlim, hl, lon)
        # predicted conflicts along the nominal profile
        se, ve = rollout(v, env, cons, ROLL_DT, ROLL_STEPS, lon)
        n_base = len(cons)
        merge_wait = self.track.merging(s_ego)
        for c in self._conflicts(v, fc, win, offs, se, ve, objs, st, e_long, cr, speed, merge_wait):
            cons.append(c)
            reasons.append("conflict")
        i0 = min(max(int((0.0 - env[0]) / 2.0), 0), len(env[1]) - 1)
        a, which = accel_now(v, float(env[1][i0]), cons, lon)
        throttle, brake = self._pedals(v, a)
        steer = self._steer(pos, yaw, v, win)
        if len(cons) > n_base:
            se, ve = rollout(v, env, cons, ROLL_DT, ROLL_STEPS, lon)
        wps, speeds = self._waypoints(pos, yaw, se, ve, win)
        return Plan(
            np.array([throttle, steer, brake], np.float32),
            a,
            wps,
            speeds,
            "free" if which < 0 else reasons[which],
            win.xy,
        )

    # ------------------------------------------------------------------ conflicts
    def _conflicts(self, v, fc, win, offs, se, ve, objs, st_now, e_long_now, cr_now, speed, merge_wait):
        """Constraints from forecast hypotheses entering the corridor while the ego is there
        (``merge_wait``: :meth:`RouteTrack.merging` at the ego, None outside lane changes)."""
        if len(fc) == 0:
            return []
        p, hl, hw = self.p, self.hl, self.hw
        h, t = fc.pos.shape[:2]
        pts = fc.pos.reshape(-1, 2)
        # within the path's bounding box + 6 m (column by column: np.all(..., axis=1) cost ~15 us)
        wx, wy, px, py = win.xy[:, 0], win.xy[:, 1], pts[:, 0], pts[:, 1]
        box = (px >= wx.min() - 6.0) & (px <= wx.max() + 6.0) & (py >= wy.min() - 6.0) & (py <= wy.max() + 6.0)
        if not box.any():
            return []
        idx = box.nonzero()[0]
        st, lat, _, cr, sr = win.project(pts[idx], fc.dirn.reshape(-1, 2)[idx])
        own = fc.owner[idx // t]
        kind = objs.kind[own]
        vru = (kind == PEDESTRIAN) | (kind == BICYCLE)
        e_lat = np.abs(0.5 * objs.length[own] * sr) + np.abs(0.5 * objs.width[own] * cr)
        e_long = np.abs(0.5 * objs.length[own] * cr) + np.abs(0.5 * objs.width[own] * sr)
        o = np.zeros(len(st)) if offs is None else offs(st)
        k = idx % t
        ego_lo = se[k] - hl - 0.5 - 0.3 * ve[k]
        ego_hi = se[k] + hl + 1.0 + 0.6 * ve[k]
        hit = np.abs(lat - o) < hw + e_lat + np.where(vru, p.lat_margin_vru, p.lat_margin)
        hit &= (st + e_long > ego_lo) & (st - e_long < ego_hi) & (st > -hl)
        if not hit.any():
            return []
        out = []
        hyp = idx[hit] // t
        first = np.concatenate([[True], hyp[1:] != hyp[:-1]]).nonzero()[0]
        sel = hit.nonzero()[0][first]
        for q in sel:
            i = int(own[q])
            if i in self.junction.yielding:
                continue  # right-of-way traffic far enough to brake for the ego (junction rules)
            s_lo = float(st[q] - e_long[q])
            if s_lo < hl - 0.5:
                continue  # it would reach the ego from the side or behind
            if cr[q] > 0.7:  # joining the ego's lane ahead: a leader
                gap = float(st_now[i] - e_long_now[i] - hl)
                if gap > 0.0:
                    out.append((gap, float(max(speed[i] * cr_now[i], 0.0)), p.leader_s0, p.headway))
                elif merge_wait is not None and not vru[q]:
                    # the ego is changing lanes in front of it: wait for a gap before the change
                    out.append((merge_wait, 0.0, 0.2, 0.0))
                continue
            margin = p.stop_margin_vru if vru[q] else p.stop_margin
            gap = s_lo - hl - margin
            if v * v / (2.0 * max(gap, 0.05)) > p.commit_decel and self._can_clear(
                v, float(st[q] + e_long[q]), float(fc.taus[k[q]])
            ):
                continue  # too late to stop comfortably, early enough to get through first
            out.append((gap, 0.0, 0.3, 0.0))
        return out

    def _can_clear(self, v: float, s_far: float, t_arrive: float) -> bool:
        """Whether the ego, accelerating, gets its rear past station ``s_far`` (m) at least
        ``clear_buffer`` s before ``t_arrive`` (s)."""
        t = float(travel_time(s_far + self.hl + 1.0, v, self.lon.accel, max(v, 10.0)))
        return t < t_arrive - self.p.clear_buffer

    # ------------------------------------------------------------------ control
    def _pedals(self, v: float, a: float) -> tuple[float, float]:
        veh = self.vehicle
        need = a + veh.drag * v
        if need >= 0.0:
            return float(clip(need / veh.max_accel, 0.0, 1.0)), 0.0
        if v < 0.05 and a < 0.0:
            return 0.0, 1.0
        return 0.0, float(clip(-need / veh.max_brake, 0.0, 1.0))

    def _steer(self, pos: np.ndarray, yaw: float, v: float, win) -> float:
        p = self.p
        ld = float(
            clip(p.lookahead_min + p.lookahead_gain * v, p.lookahead_min, p.lookahead_max)
        )
        c, s = np.cos(yaw), np.sin(yaw)
        dx, dy = win.xy[:, 0] - pos[0], win.xy[:, 1] - pos[1]
        x, y = c * dx + s * dy, -s * dx + c * dy
        d2 = x * x + y * y
        ok = ((d2 >= ld * ld) & (x > 0.0)).nonzero()[0]
        k = int(ok[0]) if len(ok) else len(x) - 1
        alpha = np.arctan2(y[k], x[k])
        dist = max(float(np.sqrt(d2[k])), 1e-3)
        delta = np.arctan2(2.0 * self.vehicle.wheelbase * np.sin(alpha), dist)
        return float(clip(delta / self.vehicle.max_steer, -1.0, 1.0))

    def _waypoints(self, pos, yaw, se, ve, win) -> tuple[np.ndarray, np.ndarray]:
        every = int(round(WAYPOINT_DT / ROLL_DT))
        s, vv = se[every - 1 :: every][:N_WAYPOINTS], ve[every - 1 :: every][:N_WAYPOINTS]
        xy = stack_xy(np.interp(s, win.st, win.xy[:, 0]), np.interp(s, win.st, win.xy[:, 1]))
        return world_to_local_2d(xy, pos, yaw).astype(np.float32), vv.astype(np.float32)
