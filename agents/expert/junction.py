"""Traffic rules at junctions: red and yellow lights, stop signs, and yielding before entering.

Lights and stop signs are road furniture, known to every agent. For each junction entry ahead
(``route_track.JunctionEntry``) the rules add stop constraints for the ego centre:

- red light: stop before the line (unless stopping is no longer possible, then go through);
- yellow light: stop if the line can be reached at <= ``YELLOW_DECEL``; the decision is kept;
- stop sign: come to a full stop within the checked zone before the line, once;
- yield: before the wait point (the stop line, or once allowed past it, just before the first
  connector crossing ours), wait while a vehicle that is *not* going to stop
  (``prediction.will_stop``) would reach a connector crossing ours while the ego, starting now,
  would be in it (time windows with buffers). This covers minor-road and all-way-stop entries,
  unprotected turns across oncoming traffic, red-light runners and priority takers alike.
  Vehicles with the right of way (major road, oncoming traffic when turning left) that are far
  enough to brake gently for the ego do not hold it forever at dense flows; violators (red-light
  runners, priority takers) are never assumed to brake.
"""

from __future__ import annotations

import numpy as np
from v2xbench.envs.v2x_intersection.town.model import LEFT, MERGE, RIGHT, STOP, STRAIGHT
from v2xbench.envs.v2x_intersection.traffic.signals import RED, YELLOW

from .lanes import LaneMap
from .objects import Objects
from .prediction import Forecast
from .prediction_jit import HAVE_JIT, travel_time_kernel
from .route_track import RouteTrack

YELLOW_DECEL = 3.5  # m/s^2: stop at yellow when this suffices
RED_GIVE_UP_DECEL = 7.0  # m/s^2: past this, a light that turned red is run rather than braked for
SIGN_STOP_BEFORE = 2.0  # m, ego centre stops this far before a stop-sign line (front just past it)
SIGN_ZONE = 6.0  # m before the line in which the stop is checked
BUFFER_BEFORE, BUFFER_AFTER = 1.0, 1.8  # s, time gaps kept before / after a crossing vehicle
EGO_PULL_ACCEL = 1.8  # m/s^2, the ego's assumed acceleration when it pulls away
EGO_JUNCTION_SPEED = 8.0  # m/s, assumed crossing speed cap
COMMIT_DECEL = 4.5  # m/s^2: past the point where this would be needed to stop, the ego is committed
ASSERT_DECEL = 5.0  # m/s^2 a right-of-way vehicle may be asked to brake at for the ego
ASSERT_REACTION = 0.5  # s, its reaction time once the ego is in its way
ASSERT_MAX_T_IN = 4.0  # s: only when the ego is that close to the conflict
STANDING_PULL_ACCEL = 2.0  # m/s^2 a standing right-of-way vehicle is assumed to pull away at
STANDING_CLEAR_M = 8.0  # m: a standing vehicle farther than this from the conflict lets the ego go
SECOND_CHANCE_DECEL = (
    3.5  # m/s^2: past the wait point, still stop short of a conflict if this suffices
)


def _end_heading(town, lane: int) -> float:
    p = town.lanes[lane].points
    return float(np.arctan2(p[-1, 1] - p[-2, 1], p[-1, 0] - p[-2, 0]))


def travel_time(d: np.ndarray, v: np.ndarray, a: np.ndarray, vmax: np.ndarray) -> np.ndarray:
    """Time (s) to cover ``d`` m from speed ``v`` at acceleration ``a`` (capped at ``vmax``;
    ``inf`` where a braking actor stops first). Vectorized."""
    if HAVE_JIT:
        flat = _flat_args(d, (v, a, vmax))
        if flat is not None:  # the usual case, without broadcast_arrays' ~5-10 us
            return travel_time_kernel(*flat)
        b = np.broadcast_arrays(np.asarray(d, float), np.asarray(v, float), np.asarray(a, float),
                                np.asarray(vmax, float))
        return travel_time_kernel(*(np.ravel(x) for x in b)).reshape(b[0].shape)
    d, v = np.maximum(np.asarray(d, float), 0.0), np.maximum(np.asarray(v, float), 0.0)
    a, vmax = np.asarray(a, float), np.maximum(np.asarray(vmax, float), v)
    out = np.full(np.broadcast(d, v, a).shape, np.inf)
    pos = a > 1e-3
    t_acc = np.where(pos, (vmax - v) / np.maximum(a, 1e-3), 0.0)
    d_acc = v * t_acc + 0.5 * a * t_acc**2
    disc = np.maximum(v * v + 2.0 * a * d, 0.0)
    t_short = np.where(pos, (-v + np.sqrt(disc)) / np.maximum(a, 1e-3), 0.0)
    t_pos = np.where(d <= d_acc, t_short, t_acc + (d - d_acc) / np.maximum(vmax, 1e-3))
    neg = a < -1e-3
    reach = v * v + 2.0 * a * d >= 0.0
    t_neg = np.where(reach, (-v + np.sqrt(disc)) / np.minimum(a, -1e-3), np.inf)
    t_zero = np.where(v > 0.05, d / np.maximum(v, 1e-6), np.where(d <= 0.0, 0.0, np.inf))
    out = np.where(pos, t_pos, np.where(neg, t_neg, t_zero))
    return np.where(d <= 0.0, 0.0, out)


def _flat_args(d, rest: tuple) -> tuple | None:
    """``(d, *rest)`` as equal-length 1-D float64 arrays when ``d`` is one and each of ``rest`` is
    one of its length or a Python / NumPy float (filled to it: the values ``np.broadcast_arrays``
    would give), else ``None``."""
    if type(d) is not np.ndarray or d.ndim != 1 or d.dtype != np.float64:
        return None
    n = d.shape[0]
    out = [d]
    for x in rest:
        if type(x) is float or type(x) is np.float64:
            out.append(np.full(n, float(x)))
        elif type(x) is np.ndarray and x.shape == (n,) and x.dtype == np.float64:
            out.append(x)
        else:
            return None
    return tuple(out)


class JunctionRules:
    """Stateful junction rules along one route (see module docstring).

    Args:
        track: the route.
        lmap: the town's lane map.
        half_length: ego half length (m).
    """

    def __init__(self, track: RouteTrack, lmap: LaneMap, half_length: float) -> None:
        self.track, self.lmap, self.half = track, lmap, half_length
        self.stopped = [False] * len(track.entries)
        self.yellow: list[str | None] = [None] * len(track.entries)
        self._conf: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
        self._prio: dict = {}
        self._first_conf: dict[int, float] = {}
        self.yielding: set[int] = set()

    def _conflict_branches(
        self, connector: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per branch: ``(crosses (B,) bool, arc length on the branch of its first conflict with
        ``connector`` (B,), station of that conflict on ``connector`` (B,), the other connector
        (B,))``."""
        if connector in self._conf:
            return self._conf[connector]
        nb = len(self.lmap.br_start)
        hit, d_br, s_me = np.zeros(nb, bool), np.full(nb, np.inf), np.zeros(nb)
        via = np.full(nb, -1, np.int64)
        for other, s_mine, s_other in self.lmap.conflicts(connector):
            for b, lanes in enumerate(self.lmap.br_lanes):
                if other in lanes and lanes[other] + s_other < d_br[b]:
                    hit[b], d_br[b], s_me[b], via[b] = True, lanes[other] + s_other, s_mine, other
        self._conf[connector] = (hit, d_br, s_me, via)
        return self._conf[connector]

    def _has_priority(self, e, other: int) -> bool:
        """Whether traffic on connector ``other`` has the right of way over the ego's entry ``e``:
        a major approach when the ego comes from a stop lane, or oncoming traffic going straight
        or right when the ego turns left."""
        key = (e.connector, other)
        if key in self._prio:
            return self._prio[key]
        town = self.track.town
        j = town.junctions[e.junction]
        oc = town.lanes[other]
        approach = oc.predecessors[0] if oc.predecessors else -1
        prio = False
        if approach >= 0:
            if e.stop_sign and approach not in j.stop_lanes and j.control != STOP:
                prio = True
            elif e.turn == LEFT and oc.turn in (STRAIGHT, RIGHT):
                h_me = _end_heading(town, e.lane)
                h_other = _end_heading(town, approach)
                prio = abs((h_other - h_me + np.pi) % (2 * np.pi) - np.pi) > 0.75 * np.pi
        self._prio[key] = prio
        return prio

    def constraints(
        self, s_ego: float, v: float, lane_signal: np.ndarray, objs: Objects, fc: Forecast
    ) -> list[tuple[float, float, float, float, str]]:
        """Stop constraints ``(gap, 0, s0, headway, reason)`` for the junction entries ahead."""
        out = []
        self.yielding: set[int] = set()
        town = self.track.town
        for k, e in enumerate(self.track.entries):
            if (e.s_exit < s_ego and e.connector >= 0) or e.s_line - s_ego > max(
                60.0, 4.0 * v + 20.0
            ):
                continue
            d_line = e.s_line - s_ego
            if d_line > 0.0:
                stop = self._signal_and_sign(k, e, d_line, v, lane_signal)
                if stop is not None:
                    out.append(stop)
            if e.connector < 0:
                continue
            control = town.junctions[e.junction].control
            if control == MERGE or d_line > max(30.0, 2.5 * v + 10.0):
                continue
            wait = d_line - (SIGN_STOP_BEFORE if e.stop_sign else self.half + 0.3)
            self._signal = lane_signal
            if not e.stop_sign or self.stopped[k]:  # wait inside, clear of the lanes crossed later
                inside = e.s_enter + self._inside_wait(e) - s_ego
                if inside > e.s_enter - s_ego + self.half + 0.5:
                    wait = max(wait, inside)
            self._wait = wait
            threat = self._assess(e, s_ego, v, objs, fc)
            if not threat:
                continue
            if wait > -0.5 and v * v / (2.0 * max(wait, 0.05)) < COMMIT_DECEL:
                out.append((max(wait, 0.0), 0.0, 0.2, 0.0, "yield"))
                continue
            # past the wait point: stop short of the threatened conflict if that is still gentle
            short = e.s_enter + self.first_threat - s_ego - self.half - 3.0
            if short > 0.0 and v * v / (2.0 * short) < SECOND_CHANCE_DECEL:
                out.append((short, 0.0, 0.2, 0.0, "yield"))
        return out

    def _inside_wait(self, e) -> float:
        """Connector station (m) where the ego may wait inside the junction: before every lane
        it crosses with right-of-way traffic, its box clear of them."""
        key = ("inside", e.connector)
        if key not in self._prio:
            st = [
                self.lmap.clear_station(e.connector, o, self.half, 0.5 * 1.9)
                for o, _, _ in self.lmap.conflicts(e.connector)
                if self._has_priority(e, o)
            ]
            self._prio[key] = min(st, default=-np.inf)
        return self._prio[key]

    def _first_conflict(self, connector: int) -> float:
        """Station (m) on ``connector`` of its first conflict with another connector."""
        if connector not in self._first_conf:
            conf = self.lmap.conflicts(connector)
            self._first_conf[connector] = min((c[1] for c in conf), default=0.0)
        return self._first_conf[connector]

    def _signal_and_sign(self, k, e, d_line, v, lane_signal):
        target = d_line - self.half - 0.3
        if e.signal:
            sig = int(lane_signal[e.lane])
            if sig == YELLOW and self.yellow[k] is None:
                self.yellow[k] = "stop" if target > v * v / (2.0 * YELLOW_DECEL) - 0.5 else "go"
            elif sig not in (YELLOW, RED):
                self.yellow[k] = None
            if sig == RED or (sig == YELLOW and self.yellow[k] == "stop"):
                if v * v / (2.0 * max(target + self.half, 0.1)) > RED_GIVE_UP_DECEL:
                    return None
                return (max(target, 0.0), 0.0, 0.2, 0.0, "red" if sig == RED else "yellow")
        if e.stop_sign and not self.stopped[k]:
            if 0.0 <= d_line <= SIGN_ZONE and v < 0.25:
                self.stopped[k] = True
                return None
            return (max(d_line - SIGN_STOP_BEFORE, 0.0), 0.0, 0.2, 0.0, "stop_sign")
        return None

    def _assess(self, e, s_ego, v, objs: Objects, fc: Forecast) -> bool:
        """Whether a vehicle that will not stop threatens the ego's crossing of entry ``e``;
        right-of-way vehicles that can still brake gently for the ego are added to
        ``self.yielding`` (the planner then leaves their conflicts to them)."""
        crosses, d_br, s_br, via = self._conflict_branches(e.connector)
        # moving vehicles (forecast) and standing ones near the junction, which may pull away
        centre = self.track.town.junctions[e.junction].center
        d2 = ((objs.pos - centre) ** 2).sum(1)
        near = d2[fc.still_owner] < 45.0**2
        s_own, s_br0, s_s0 = fc.still_owner[near], fc.still_branch[near], fc.still_s0[near]
        owner = np.concatenate([fc.owner, s_own])
        branch = np.concatenate([fc.branch, s_br0])
        s0 = np.concatenate([fc.s0, s_s0])
        fstops = np.concatenate([fc.stops, np.zeros(len(s_own), bool)])
        still = np.concatenate([np.zeros(len(fc), bool), np.ones(len(s_own), bool)])
        on = ((branch >= 0) & crosses[np.maximum(branch, 0)]).nonzero()[0]
        if len(on) == 0:
            return False
        d_conf, s_mine = d_br[branch[on]], s_br[branch[on]]
        own = owner[on]
        half_o = 0.5 * objs.length[own]
        dist = d_conf - s0[on]
        stop_s = self.lmap.br_stop_s[branch[on]]
        stops = fstops[on] & (stop_s < d_conf) & (s0[on] + half_o < stop_s)
        live = (dist > -(half_o + 3.0)) & ~stops
        if not live.any():
            return False
        speed = objs.speed[own]
        prio = np.array([self._has_priority(e, int(o)) for o in via[branch[on]]])
        # right-of-way traffic that brakes (a queue, a hesitation) may drive on: no braking assumed
        acc = objs.accel[own].clip(np.where(prio, 0.0, -1.5), 1.5)
        acc = np.where(still[on], STANDING_PULL_ACCEL, acc)
        n = len(on)
        vmax_o = np.maximum(speed, 14.0)
        t_o = travel_time(
            np.concatenate([dist - half_o - 1.5, dist + half_o + 3.0]),
            np.concatenate([speed, speed]),
            np.concatenate([acc, acc]),
            np.concatenate([vmax_o, vmax_o]),
        )
        t_in_o, t_out_o = t_o[:n], t_o[n:]
        d_mine = e.s_enter + s_mine - s_ego
        # the assertive check assumes the ego first moves up to its wait point (if not there yet)
        w = max(self._wait, 0.0)
        d_e = np.concatenate(
            [d_mine - self.half - 1.0, d_mine + self.half + 3.0, d_mine - w - self.half - 1.0]
        )
        v_e = np.concatenate([np.full(2 * n, v), np.zeros(n)])
        t_e = travel_time(d_e, v_e, EGO_PULL_ACCEL, max(EGO_JUNCTION_SPEED, v))
        t_in_e, t_out_e, t_in_w = t_e[:n], t_e[n : 2 * n], t_e[2 * n :]
        hit = live & (t_in_o < t_out_e + BUFFER_AFTER) & (t_out_o > t_in_e - BUFFER_BEFORE)
        if not hit.any():
            return False
        # right-of-way traffic far enough to brake gently for the ego may be made to (dense flows)
        t_react = np.minimum(t_in_e, t_in_w) + ASSERT_REACTION
        room = dist - half_o - 4.0 - speed * t_react - speed * speed / (2.0 * ASSERT_DECEL)
        # a standing vehicle only matters when it has the right of way and no red light or stop sign
        # holds it before the junction
        stop_lane = np.maximum(self.lmap.br_stop_lane[branch[on]], 0)
        sig = self._signal[stop_lane]
        rule = (sig == RED) | (sig == YELLOW) | self.lmap.br_stop_sign[branch[on]]
        held = (stop_s > s0[on] + half_o - 1.0) & (stop_s < d_conf) & rule
        live &= ~still[on] | (prio & ~held)
        hit &= live
        close = np.minimum(t_in_e, t_in_w) < ASSERT_MAX_T_IN
        moving_yields = (room > 0.0) & (speed > 1.0) & (acc < 0.5)
        standing_yields = still[on] & (dist - half_o > STANDING_CLEAR_M)
        yields = prio & close & (moving_yields | standing_yields)
        self.yielding.update(set(own[hit & yields].tolist()) - set(own[hit & ~yields].tolist()))
        if (hit & ~yields).any():
            self.first_threat = float(s_mine[hit & ~yields].min())
        self.debug = dict(
            own=own,
            hit=hit,
            yields=yields,
            prio=prio,
            room=room,
            t_in_o=t_in_o,
            t_out_o=t_out_o,
            t_in_e=t_in_e,
            t_out_e=t_out_e,
            dist=dist,
        )
        return bool((hit & ~yields).any())
