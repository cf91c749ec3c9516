"""Lateral manoeuvres: going around static obstacles and making room for emergency vehicles.

A manoeuvre is a lateral offset ``O`` (m, left positive) of the route path, ramped in and out
with a cosine profile over route arc lengths ``s0 -> s1`` (in) and ``s2 -> s3`` (out).

- Obstacles: static objects in the ego's corridor ahead are grouped into a cluster (items less
  than ``CLUSTER_GAP_M`` apart); the smallest offset whose corridor clears every standing object
  around the cluster with a margin is chosen among those the road allows (in-lane nudge, a
  same-direction neighbour lane, or the opposite lane of a two-way road, the latter penalized).
  Leaving the own lane needs the target lane clear: no vehicle beside or closing from behind,
  and, in the opposite lane, no oncoming vehicle reaching the cluster's end before the ego is
  back. Before the ego reaches the cluster a manoeuvre that is no longer safe is aborted.
- Emergency vehicles closing in from behind in the ego's lane: move to a neighbour lane (right
  first) while it passes.

Offsets are capped at ``MAX_OFFSET`` (< 3 m) so the ego stays within the route-progress capture
radius of the event monitor. Only a move into a same-direction neighbour lane around a short
cluster may go as far as the neighbour lane's centre (at most ``LANE_CHANGE_MAX_OFFSET``): on wide
lanes (Town12's reach 4 m) an obstacle that closes the ego lane up to its edge leaves no corridor
within 2.9 m; the route progress then waits while the ego is beyond the capture radius and catches
up once it is back, which it does within the monitor's search window when the shifted stretch is
shorter than ``WIDE_STRETCH_MAX_M``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from v2xbench.envs.v2x_intersection.core.classes import BICYCLE, PEDESTRIAN

from .junction import travel_time
from .objects import Objects
from .route_track import PathWindow, RouteTrack
from .scalar import clip

MAX_OFFSET = 2.9  # m
LANE_CHANGE_MAX_OFFSET = 4.0  # m, to the centre of a same-direction neighbour lane
WIDE_STRETCH_MAX_M = 35.0  # m, cluster + ego length + 2.5 m (monitor window: 40 route points)
IN_LANE_SLACK = 0.3  # m the ego centre may leave its lane centre band beyond the lane edge
CLUSTER_GAP_M = 10.0  # m between obstacles of one cluster
STATIC_MARGINS = (0.6, 0.45, 0.3)  # m lateral clearance to standing objects, tried in order
VRU_MARGIN = 1.0  # m lateral clearance to pedestrians and bicycles
OPPOSITE_PENALTY = 2.0  # m-equivalent cost of using the opposite lane
PASS_SPEED = 13.0  # m/s, speed cap while in the opposite lane
PASS_ACCEL = 2.3  # m/s^2 while overtaking through the opposite lane (nuPlan comfort: 2.4)
PASS_EXIT_M = 6.0  # m past the obstacle's end (plus half the ego) where the ego is back in lane
PASS_BUFFER_S = 0.7  # s kept between the ego's return and the oncoming vehicle's arrival
INVADER_MARGIN = 0.4  # m kept from oncoming vehicles that cut into the ego's lane
ABORT_MAX_OFFSET = 0.6  # m: beyond this shift a started pass is completed, not aborted


def _ego_lane(win: PathWindow) -> int:
    """Route lane id under the ego (station 0 of the path window)."""
    return int(win.lanes[min(int(win.st.searchsorted(0.0)), len(win.st) - 1)])


@dataclass
class Manoeuvre:
    """An active lateral offset (route arc lengths in m)."""

    offset: float
    s0: float
    s1: float
    s2: float
    s3: float
    kind: str  # "obstacle" | "emergency"
    invades: bool  # uses the opposite lane
    s_obst: tuple[float, float] = (0.0, 0.0)  # cluster start / end stations (obstacles)

    def value(self, s: np.ndarray) -> np.ndarray:
        """Offset (m) at route arc lengths ``s``."""
        up = np.clip((s - self.s0) / max(self.s1 - self.s0, 1e-3), 0.0, 1.0)
        if np.isfinite(self.s2):
            down = np.clip((s - self.s2) / max(self.s3 - self.s2, 1e-3), 0.0, 1.0)
        else:  # held until further notice (emergency vehicle still behind)
            down = np.zeros_like(np.asarray(s, float))
        w = 0.5 - 0.5 * np.cos(np.pi * up) - (0.5 - 0.5 * np.cos(np.pi * down))
        return self.offset * w


class LateralPlanner:
    """Chooses and tracks lateral manoeuvres (see module docstring).

    Args:
        track: the route. half_length, half_width: ego box halves (m).
    """

    def __init__(self, track: RouteTrack, half_length: float, half_width: float) -> None:
        self.track, self.hl, self.hw = track, half_length, half_width
        self.man: Manoeuvre | None = None
        self.speed_cap = np.inf

    def offsets(self, s_ego: float):
        """``f(st) -> offsets`` for stations relative to the ego (``None`` when none is active)."""
        if self.man is None:
            return None
        man = self.man
        return lambda st: man.value(st + s_ego)

    def _lane_room(self, lane: int, wide: bool = False) -> tuple[float, float, float]:
        """``(right limit, left limit, opposite-lane threshold)`` of offsets (m) on ``lane``;
        ``wide``: a same-direction neighbour may be used up to its centre (see module doc)."""
        ix = self.track.town.index
        ln = self.track.town.lanes[lane]
        w = float(ix.width[lane])
        nudge = w / 2.0 - self.hw + IN_LANE_SLACK

        def reach(nb: int) -> float:
            if not wide or nb < 0:
                return min(w, MAX_OFFSET)
            return min(0.5 * (w + float(ix.width[nb])), LANE_CHANGE_MAX_OFFSET)

        left = reach(ln.left) if (ln.left >= 0 or ln.opposite >= 0) else nudge
        right = -reach(ln.right) if ln.right >= 0 else -nudge
        opp = nudge if (ln.left < 0 and ln.opposite >= 0) else np.inf
        return right, left, opp

    def update(
        self,
        s_ego: float,
        v: float,
        win: PathWindow,
        objs: Objects,
        st: np.ndarray,
        lat: np.ndarray,
        cos_r: np.ndarray,
        sin_r: np.ndarray,
    ) -> None:
        """Start, keep, abort or finish a manoeuvre.

        Args:
            s_ego: ego route arc length (m). v: ego speed (m/s).
            win: the path window (unshifted route). objs: the object list.
            st, lat, cos_r, sin_r: the objects in the route frame (``PathWindow.project``).
        """
        self.speed_cap = np.inf
        e_lat = np.abs(0.5 * objs.length * sin_r) + np.abs(0.5 * objs.width * cos_r)
        e_long = np.abs(0.5 * objs.length * cos_r) + np.abs(0.5 * objs.width * sin_r)
        speed = objs.speed
        if self.man is not None and s_ego > self.man.s3:
            self.man = None
        man = self.man
        if man is not None and man.kind != "obstacle" and np.isfinite(man.s2) and s_ego >= man.s2:
            # an invader / emergency shift ramping out gives way to a pass around an obstacle
            # ahead: the ego may stand behind the obstacle before the ramp's end (a deadlock)
            self.man = None
            self._obstacle(s_ego, v, win, objs, st, lat, cos_r, e_lat, e_long, speed)
            if self.man is None:
                self.man = man
            return
        if self.man is not None:
            self._keep(s_ego, v, win, objs, st, lat, cos_r, e_lat, e_long, speed)
            return
        if self._emergency(s_ego, v, win, objs, st, lat, cos_r, e_lat, e_long, speed):
            return
        if self._invading(s_ego, v, win, objs, st, lat, cos_r, e_lat, e_long, speed):
            return
        self._obstacle(s_ego, v, win, objs, st, lat, cos_r, e_lat, e_long, speed)

    # ------------------------------------------------------------------ obstacles
    def _intruding(self, objs, lat, e_lat, speed, half_lane: float) -> np.ndarray:
        """Standing objects reaching into the ego's lane (``half_lane``: half lane width, m)."""
        return objs.static & (speed < 0.3) & (np.abs(lat) - e_lat < half_lane - 0.1)

    def _cluster(self, v, half_lane, objs, st, lat, e_lat, e_long, speed):
        """``(start, end)`` stations (m, relative) of the obstacles blocking the corridor ahead."""
        intr = self._intruding(objs, lat, e_lat, speed, half_lane)
        block = intr & (np.abs(lat) < self.hw + e_lat + 0.3) & (st - e_long > self.hl - 0.5)
        block &= st < max(30.0, 3.0 * v + 20.0)
        if not block.any():
            return None
        lo = hi = float((st - e_long)[block].min())
        for i in st.argsort():
            if (
                not intr[i]
                or st[i] - e_long[i] > hi + CLUSTER_GAP_M
                or st[i] + e_long[i] < lo - 1.0
            ):
                continue
            hi = max(hi, float(st[i] + e_long[i]))
        return lo, hi

    def _best_offset(
        self, lane, lo, hi, objs, st, lat, e_lat, e_long, speed
    ) -> tuple[float, bool] | None:
        wide = hi - lo + 2.0 * self.hl + 2.5 < WIDE_STRETCH_MAX_M
        right, left, opp = self._lane_room(lane, wide)
        cand = np.arange(-LANE_CHANGE_MAX_OFFSET, LANE_CHANGE_MAX_OFFSET + 1e-6, 0.1)
        cand = cand[(cand >= right - 1e-6) & (cand <= left + 1e-6)]
        span = (
            (st + e_long > lo - self.hl - 4.0) & (st - e_long < hi + self.hl + 4.0) & (speed < 0.3)
        )
        vru = (objs.kind == PEDESTRIAN) | (objs.kind == BICYCLE)
        for margin in STATIC_MARGINS:
            need = self.hw + e_lat[span] + np.where(vru[span], VRU_MARGIN, margin)
            free = np.all(np.abs(lat[span][None, :] - cand[:, None]) >= need[None, :], axis=1)
            if free.any():
                c = cand[free]
                cost = np.abs(c) + np.where(c > opp, OPPOSITE_PENALTY, 0.0)
                k = int(cost.argmin())
                return float(c[k]), bool(c[k] > opp)
        return None

    def _target_clear(
        self, off, invades, s_ego, v, lo, hi, objs, st, lat, cos_r, e_lat, e_long, speed,
        strict: bool = True,
    ) -> bool:
        """No moving vehicle beside / closing from behind in the target band, and no oncoming one
        reaching the cluster end before the ego is back (relative stations: ``lo``, ``hi``).
        ``strict=False`` (a pass already begun) drops the safety buffers: a manoeuvre is aborted
        only for a real conflict, so that the ego does not stop half-turned toward the other lane."""
        moving = (speed > 0.3) & ~objs.static
        band = moving & (np.abs(lat - off) < self.hw + e_lat + 1.0)
        if not band.any():
            return True
        same = band & (cos_r > 0.5) & (np.abs(lat - off) < np.abs(lat))  # not the ego's follower
        behind_room = 8.0 + 1.5 * np.maximum(speed - v, 0.0) + 0.8 * speed
        if (same & (st > -self.hl - behind_room) & (st - e_long < self.hl + 6.0)).any():
            return False
        oncoming = band & (cos_r < -0.5) & (st > -self.hl)
        if oncoming.any():
            exit_st = hi + self.hl + (PASS_EXIT_M if strict else 2.0)  # ego back in its lane
            t_man = float(travel_time(exit_st, v, PASS_ACCEL, max(v, PASS_SPEED)))
            t_man += PASS_BUFFER_S if strict else 0.0
            if (oncoming & (st - e_long - speed * t_man < exit_st + (3.0 if strict else 0.0))).any():
                return False
        return True

    def _obstacle(self, s_ego, v, win, objs, st, lat, cos_r, e_lat, e_long, speed) -> None:
        lane = _ego_lane(win)
        half_lane = 0.5 * float(self.track.town.index.width[lane])
        cl = self._cluster(v, half_lane, objs, st, lat, e_lat, e_long, speed)
        if cl is None:
            return
        lo, hi = cl
        queued = ~objs.static & (speed < 0.3) & (np.abs(lat) < self.hw + e_lat + 0.3)
        if (queued & (st > 0.0) & (st - e_long < lo)).any():
            return  # a vehicle waits in the lane before the obstacle: queue behind it first
        k = int(clip(win.st.searchsorted(lo), 0, len(win.st) - 1))
        lane = int(win.lanes[k])
        best = self._best_offset(lane, lo, hi, objs, st, lat, e_lat, e_long, speed)
        if best is None or abs(best[0]) < 0.05:
            return
        off, invades = best
        leaves = (
            abs(off) > self.track.town.index.width[lane] / 2.0 - self.hw + IN_LANE_SLACK + 1e-6
            or invades
        )
        if leaves and not self._target_clear(
            off, invades, s_ego, v, lo, hi, objs, st, lat, cos_r, e_lat, e_long, speed
        ):
            return
        ramp = float(clip(2.0 * v + 8.0, 8.0, 25.0)) * max(abs(off) / 3.0, 0.5)
        s1 = s_ego + lo - self.hl - 1.0
        s0 = max(s1 - ramp, s_ego)
        s2 = s_ego + hi + self.hl + 1.5
        self.man = Manoeuvre(
            off, s0, max(s1, s0 + 4.0), s2, s2 + ramp, "obstacle", invades, (s_ego + lo, s_ego + hi)
        )

    def _still_clears(self, man, s_ego, objs, st, lat, e_lat, e_long, speed) -> bool:
        """Whether the manoeuvre's offset still clears every standing object around its cluster."""
        lo, hi = man.s_obst[0] - s_ego, man.s_obst[1] - s_ego
        span = (st + e_long > lo - 1.0) & (st - e_long < hi + 1.0) & (speed < 0.3)
        vru = (objs.kind == PEDESTRIAN) | (objs.kind == BICYCLE)
        need = self.hw + e_lat + np.where(vru, VRU_MARGIN, STATIC_MARGINS[-1])
        return not (span & (np.abs(lat - man.offset) < need)).any()

    def _keep(self, s_ego, v, win, objs, st, lat, cos_r, e_lat, e_long, speed) -> None:
        man = self.man
        if man.kind == "emergency":
            self._keep_emergency(s_ego, v, objs, st, lat, speed)
            return
        if man.kind == "invading":
            if np.isfinite(man.s2):
                return
            need = self._invader_offset(win, objs, st, lat, cos_r, e_lat, e_long, speed, v)
            if need is None:
                ramp = float(clip(1.5 * v + 6.0, 6.0, 15.0))
                man.s2, man.s3 = s_ego, s_ego + ramp
            elif need < man.offset:
                man.offset = need  # a wider invader: move further over
            return
        # extend the cluster with standing objects found further along, while not yet returning
        if s_ego < man.s2:
            lane = _ego_lane(win)
            intr = self._intruding(
                objs, lat, e_lat, speed, 0.5 * float(self.track.town.index.width[lane])
            )
            more = intr & (st - e_long < man.s_obst[1] - s_ego + CLUSTER_GAP_M)
            more &= st + e_long > man.s_obst[1] - s_ego
            if more.any():
                hi = float((st + e_long)[more].max())
                ramp = man.s3 - man.s2
                man.s_obst = (man.s_obst[0], s_ego + hi)
                man.s2 = max(man.s2, s_ego + hi + self.hl + 1.5)
                man.s3 = man.s2 + ramp
        before = s_ego + self.hl < man.s_obst[0] - 1.0
        if before and not self._still_clears(man, s_ego, objs, st, lat, e_lat, e_long, speed):
            self.man = None  # something moved into the chosen corridor (a door opened): replan
            return
        if man.invades or abs(man.offset) > 1.5:
            lo, hi = man.s_obst[0] - s_ego, man.s_obst[1] - s_ego
            cur = abs(float(man.value(np.array([s_ego]))[0]))
            if (
                before
                and cur < ABORT_MAX_OFFSET
                and not self._target_clear(
                    man.offset,
                    man.invades,
                    s_ego,
                    v,
                    lo,
                    hi,
                    objs,
                    st,
                    lat,
                    cos_r,
                    e_lat,
                    e_long,
                    speed,
                    strict=False,
                )
            ):
                self.man = None  # abort: back to the lane, wait behind the obstacle, plan again
                return
            self.speed_cap = PASS_SPEED if man.invades else np.inf

    # ------------------------------------------------------------------ invading oncoming traffic
    def _invader_offset(self, win, objs, st, lat, cos_r, e_lat, e_long, speed, v) -> float | None:
        """Offset (m, < 0: to the right) that keeps ``INVADER_MARGIN`` from oncoming vehicles
        reaching into the ego's lane from the left within the next few seconds; None if there
        are none (or they leave the ego room without moving)."""
        reach = np.maximum(st - e_long, 0.0) / np.maximum(speed + v, 1.0)
        onc = (cos_r < -0.5) & (speed > 0.5) & ~objs.static & (st + e_long > -self.hl) & (reach < 5.0)
        onc &= lat > 0.0
        room = lat - e_lat - INVADER_MARGIN - self.hw  # how far the ego centre may be left
        onc &= room < 0.0
        if not onc.any():
            return None
        lane = _ego_lane(win)
        right, _, _ = self._lane_room(lane)
        return float(max(room[onc].min(), right))

    def _invading(self, s_ego, v, win, objs, st, lat, cos_r, e_lat, e_long, speed) -> bool:
        """Start moving right, inside the lane, for oncoming vehicles that cut into it."""
        need = self._invader_offset(win, objs, st, lat, cos_r, e_lat, e_long, speed, v)
        if need is None or need > -0.1:
            return False
        ramp = float(clip(1.0 * v + 4.0, 4.0, 12.0))
        self.man = Manoeuvre(need, s_ego, s_ego + ramp, np.inf, np.inf, "invading", False)
        return True

    # ------------------------------------------------------------------ emergency vehicles
    def _emergency(self, s_ego, v, win, objs, st, lat, cos_r, e_lat, e_long, speed) -> bool:
        ev = objs.emergency & (st < 0.0) & (st > -90.0) & (np.abs(lat) < 2.5) & (cos_r > 0.5)
        ev &= (speed > v + 0.5) | (st > -30.0)
        if not ev.any():
            return False
        lane = _ego_lane(win)
        ln = self.track.town.lanes[lane]
        w = min(float(self.track.town.index.width[lane]), MAX_OFFSET)
        options = [o for o, nb in ((-w, ln.right), (w, ln.left)) if nb >= 0]
        for off in options:
            if self._target_clear(
                off, False, s_ego, v, 5.0, 15.0, objs, st, lat, cos_r, e_lat, e_long, speed
            ):
                ramp = float(clip(1.5 * v + 8.0, 10.0, 20.0))
                self.man = Manoeuvre(off, s_ego, s_ego + ramp, np.inf, np.inf, "emergency", False)
                self.speed_cap = 8.0
                return True
        self.speed_cap = np.inf
        return False

    def _keep_emergency(self, s_ego, v, objs, st, lat, speed) -> None:
        man = self.man
        ev = objs.emergency
        behind = ev & (st < self.hl + 12.0) & (st > -120.0)
        if np.isfinite(man.s2):
            return
        if not behind.any():
            ramp = float(clip(1.5 * v + 8.0, 10.0, 20.0))
            man.s2, man.s3 = s_ego, s_ego + ramp
        else:
            self.speed_cap = 8.0
