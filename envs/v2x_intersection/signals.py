"""Traffic-light phase plans: the state of every signal-controlled lane as a function of time.

Each signalized junction runs one phase per approach (split phasing: one approach green at a time,
then yellow, then all red), so no two signal-green flows cross. States: ``GREEN``, ``YELLOW``,
``RED``; lanes without a signal report ``NO_SIGNAL``.
"""

from __future__ import annotations

import numpy as np

from .jit import HAVE_JIT
from .jit_traffic import lane_states_kernel
from .town.model import SIGNAL, Town

NO_SIGNAL, GREEN, YELLOW, RED = -1, 0, 1, 2
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

    def states(self, t: float) -> np.ndarray:
        """``(K,)`` state of each controlled lane at time ``t`` (s)."""
        cycle = self._period * self._n_groups
        tm = (t + self._offset) % np.maximum(cycle, 1e-9)
        phase = np.floor(tm / self._period).astype(np.int64)
        within = tm - phase * self._period
        state = np.where(within < self._green, GREEN, np.where(within < self._green + self._yellow, YELLOW, RED))
        return np.where(phase == self.group, state, RED)

    def lane_states(self, t: float) -> np.ndarray:
        """``(num_lanes,)`` state per lane id (``NO_SIGNAL`` where uncontrolled)."""
        if HAVE_JIT:
            return lane_states_kernel(float(t), self.lanes, self.group, self._period, self._green, self._yellow,
                                      self._n_groups, self._offset, self.num_lanes)
        out = np.full(self.num_lanes, NO_SIGNAL, np.int64)
        out[self.lanes] = self.states(t)
        return out
