"""Traffic-light phase plans: the state of every signal-controlled lane as a function of time.

Each signalized junction runs one phase per approach (split phasing: one approach green at a time,
then yellow, then all red), so no two signal-green flows cross. States: ``GREEN``, ``YELLOW``,
``RED``; lanes without a signal report ``NO_SIGNAL``.

A scenario may override one junction's lights (CARLA's PriorityAtJunction sets the ego's light
green): :meth:`SignalPlan.force_green` makes the given lanes green and the junction's other
controlled lanes red (those green at that moment turn yellow for the junction's yellow time
first) until :meth:`SignalPlan.release`. Every reader of the lights (traffic, agents,
infractions, sensors) reads ``World.lane_signal``, so all see the override.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.jit import HAVE_JIT
from ..town.model import SIGNAL, Town
from .jit_vehicles import lane_states_kernel, phase_valid_until_kernel

NO_SIGNAL, GREEN, YELLOW, RED = -1, 0, 1, 2
#: s, margin kept before a phase boundary when reusing the last lane states (``SignalPlan.lane_states``)
BOUNDARY_SLACK_S = 1e-6
STATE_NAMES = ("green", "yellow", "red")


class SignalPlan:
    """Vectorized signal timing for one town.

    Attributes:
        lanes: ``(K,)`` signal-controlled incoming lane ids.
        junction: ``(K,)`` their junction ids. group: ``(K,)`` their phase index.
    """

    def __init__(self, town: Town) -> None:
        lanes, junc, group, period, green, yellow, n_groups, offset = [], [], [], [], [], [], [], []
        for j in town.junctions:
            if j.control != SIGNAL:
                continue
            for g, members in enumerate(j.phase_groups):
                for lid in members:
                    lanes.append(lid)
                    junc.append(j.id)
                    group.append(g)
                    period.append(j.green_s + j.yellow_s + j.all_red_s)
                    green.append(j.green_s)
                    yellow.append(j.yellow_s)
                    n_groups.append(len(j.phase_groups))
                    offset.append(j.offset_s)
        self.lanes = np.array(lanes, np.int64)
        self.junction = np.array(junc, np.int64)
        self.group = np.array(group, np.int64)
        self._period = np.array(period)
        self._green = np.array(green)
        self._yellow = np.array(yellow)
        self._n_groups = np.array(n_groups)
        self._offset = np.array(offset)
        self.num_lanes = len(town.lanes)
        self._last: tuple[float, float, np.ndarray] | None = None  # (t, valid until, lane states)
        self._yellow_of = {j.id: j.yellow_s for j in town.junctions if j.control == SIGNAL}
        #: the active override: (green lanes, red lanes, lanes yellow first, from t, yellow until)
        self._forced: tuple[np.ndarray, np.ndarray, np.ndarray, float, float] | None = None

    def states(self, t: float) -> np.ndarray:
        """``(K,)`` state of each controlled lane at time ``t`` (s)."""
        cycle = self._period * self._n_groups
        tm = (t + self._offset) % np.maximum(cycle, 1e-9)
        phase = np.floor(tm / self._period).astype(np.int64)
        within = tm - phase * self._period
        state = np.where(within < self._green, GREEN, np.where(within < self._green + self._yellow, YELLOW, RED))
        return np.where(phase == self.group, state, RED)

    def force_green(self, lanes: np.ndarray | list[int], t: float) -> None:
        """From time ``t`` (s) on: ``lanes`` (signal-controlled incoming lanes of one junction)
        green, the junction's other controlled lanes red, those that are green at ``t`` yellow for
        the junction's yellow time first; until :meth:`release`.

        Raises:
            ValueError: a lane that no signal controls, or lanes of more than one junction.
        """
        lanes = np.asarray(lanes, np.int64).reshape(-1)
        member = np.isin(lanes, self.lanes)
        if len(lanes) == 0 or not member.all():
            bad = lanes[~member].tolist() if len(lanes) else "none given"
            raise ValueError(f"force_green: lanes {bad} are not signal-controlled")
        juncs = np.unique(self.junction[np.isin(self.lanes, lanes)])
        if len(juncs) != 1:
            raise ValueError(f"force_green: lanes {lanes.tolist()} belong to junctions "
                             f"{juncs.tolist()}; one junction at a time")
        self.release()
        others = self.lanes[(self.junction == juncs[0]) & ~np.isin(self.lanes, lanes)]
        was_green = others[self.lane_states(t)[others] == GREEN]
        self._forced = (lanes, others, was_green, float(t), float(t) + self._yellow_of[int(juncs[0])])

    def release(self) -> None:
        """End the override of :meth:`force_green` (the fixed-time plan runs on)."""
        self._forced = None

    def lane_states(self, t: float) -> np.ndarray:
        """``(num_lanes,)`` state per lane id (``NO_SIGNAL`` where uncontrolled), the override of
        :meth:`force_green` applied from its start time on.

        The states change only at phase boundaries, so the last answer is kept and returned
        again (the same array: read it, never write into it) for any later ``t`` before the
        next boundary (:meth:`_valid_until`); a tick's call then costs a comparison instead of a
        kernel call."""
        base = self._plan_states(t)
        if self._forced is None or t < self._forced[3]:
            return base
        green, red, was_green, _, yellow_until = self._forced
        out = base.copy()
        out[red] = RED
        if t < yellow_until:
            out[was_green] = YELLOW
        out[green] = GREEN
        return out

    def _plan_states(self, t: float) -> np.ndarray:
        """The fixed-time plan's lane states (cached until the next phase boundary)."""
        last = self._last
        if last is not None and last[0] <= t < last[1]:
            return last[2]
        if HAVE_JIT:
            t = float(t)
            out = lane_states_kernel(t, self.lanes, self.group, self._period, self._green, self._yellow,
                                     self._n_groups, self._offset, self.num_lanes)
            until = phase_valid_until_kernel(t, self._period, self._green, self._yellow, self._n_groups,
                                             self._offset, BOUNDARY_SLACK_S)
        else:
            out = np.full(self.num_lanes, NO_SIGNAL, np.int64)
            out[self.lanes] = self.states(t)
            until = self._valid_until(t)
        self._last = (t, until, out)
        return out

    def _valid_until(self, t: float) -> float:
        """A time before which no controlled lane changes state after ``t``: the nearest phase
        boundary (end of green, of yellow, of the phase) less ``BOUNDARY_SLACK_S``, far above the
        float64 rounding of ``states``' arithmetic, so every ``t' in [t, valid_until)`` gives the
        same states as ``t``. ``t`` itself where a plan has a non-positive period."""
        if len(self.lanes) == 0:
            return math.inf
        if not (self._period > 0.0).all():
            return t
        cycle = np.maximum(self._period * self._n_groups, 1e-9)
        tm = (t + self._offset) % cycle
        within = tm - np.floor(tm / self._period) * self._period
        ends_green = self._green
        ends_yellow = self._green + self._yellow
        nxt = np.where(within < ends_green, ends_green, np.where(within < ends_yellow, ends_yellow, self._period))
        return t + float((nxt - within).min()) - BOUNDARY_SLACK_S
