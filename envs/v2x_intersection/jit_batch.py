"""The traffic's move (``World.move_traffic``) of many worlds in one numba call.

Called once per world, ``jit_tick.traffic_tick_kernel`` costs ~11 us of numba's dispatch alone
(79 arguments to type and unbox) and runs with cold caches. :class:`TrafficBatch` keeps each
world's arguments in numba typed lists, refreshed only when they change (a reset, a new lane-state
array, a new plan), and :func:`traffic_batch_kernel` calls the same kernel world after world,
so the batch pays one dispatch per tick. A single world (``World.move_traffic``) uses a batch of
one: :func:`traffic_one_kernel` takes 7 arguments instead of 79. Each world sees exactly the call
it would make alone (``tests/test_jit_batch.py`` and ``tests/test_batch.py`` compare, byte for
byte).
"""

from __future__ import annotations

import numpy as np

from .jit import HAVE_JIT, _njit
from .jit_tick import traffic_tick_kernel
from .pedestrians import ego_is_vehicle
from .traffic import flat_plans

if HAVE_JIT:  # pragma: no branch
    from numba.typed import List
else:  # pragma: no cover
    List = list


@_njit
def new_list(item):  # pragma: no cover
    """A typed list holding ``item`` (its type fixes the list's)."""
    out = List()
    out.append(item)
    return out


@_njit
def list_append(lst, item):  # pragma: no cover
    lst.append(item)


@_njit
def list_set(lst, i, item):  # pragma: no cover
    lst[i] = item


@_njit
def traffic_batch_kernel(order, controls, ego_ok, consts, signals, plans):  # pragma: no cover
    """``traffic_tick_kernel`` for worlds ``order``: world ``w``'s ``(throttle, steer, brake)`` is
    ``controls[w]``, its lane states ``signals[w]``, its ``traffic.flat_plans`` ``plans[w]`` and
    ``consts[w]`` = ``(bicycle params, walkers, jaywalk probability per tick, *episode arguments)``.

    Returns:
        ``(rows, counts)``: the rows to respawn of ``order[k]`` are ``rows[sum(counts[:k]):][:counts[k]]``.
    """
    m = order.shape[0]
    counts = np.zeros(m, np.int64)
    parts = List()
    total = 0
    for k in range(m):
        w = order[k]
        c = consts[w]
        p = plans[w]
        r = traffic_tick_kernel(controls[w, 0], controls[w, 1], controls[w, 2], c[0], signals[w], p[0], p[1], p[2],
                                c[1], ego_ok[w], c[2], *c[3:])
        counts[k] = r.shape[0]
        total += r.shape[0]
        parts.append(r)
    rows = np.empty(total, np.int64)
    j = 0
    for k in range(m):
        r = parts[k]
        for q in range(r.shape[0]):
            rows[j] = r[q]
            j += 1
    return rows, counts


@_njit
def traffic_one_kernel(throttle, steer, brake, ego_ok, consts, signals, plans):  # pragma: no cover
    """``traffic_tick_kernel`` for the one world of :class:`TrafficBatch` lists of length 1."""
    c = consts[0]
    p = plans[0]
    return traffic_tick_kernel(throttle, steer, brake, c[0], signals[0], p[0], p[1], p[2], c[1], ego_ok, c[2],
                               *c[3:])


class TrafficBatch:
    """``World.move_traffic`` for the worlds of a batch in one kernel call (numba only).

    The typed lists are built on the first :meth:`step` and updated entry by entry when a world's
    arguments change. Should the worlds' arguments not share one numba type (they do for every
    configuration of one batch), :meth:`step` returns ``False`` and the caller moves the worlds
    one by one.
    """

    def __init__(self, worlds: list) -> None:
        self.worlds = worlds
        self._lists: tuple | None = None  # (consts, signals, plans) typed lists, one entry per world
        self._keys: list[list] = [[None] * len(worlds) for _ in range(3)]  # what each entry was built from
        self._broken = False

    def _entries(self, w) -> tuple:
        return w._traffic_consts(), w.lane_signal, flat_plans(w.plans)

    def _sync(self, ids: list[int]) -> None:
        if self._lists is None:
            firsts = self._entries(self.worlds[0])
            lists = tuple(new_list(x) for x in firsts)
            for w in self.worlds[1:]:
                for lst, x in zip(lists, self._entries(w)):
                    list_append(lst, x)
            self._lists = lists
            self._keys = [[e[j] for e in (self._entries(w) for w in self.worlds)] for j in range(3)]
            return
        for i in ids:
            for j, (lst, x) in enumerate(zip(self._lists, self._entries(self.worlds[i]))):
                if x is not self._keys[j][i]:
                    list_set(lst, i, x)
                    self._keys[j][i] = x

    def step(self, ids: list[int], controls: np.ndarray) -> bool:
        """Move worlds ``ids`` under ``controls[i]`` (checked ``(N, 3)``); ``False``: not done,
        move them one by one."""
        if self._broken or any(getattr(w, "table", None) is None for w in self.worlds):
            return False
        n = len(self.worlds)
        ctl = np.zeros((n, 3))
        ego_ok = np.zeros(n, np.bool_)
        for i in ids:
            w = self.worlds[i]
            ctl[i] = w._take_control(controls[i])
            w.update_signals()
            ego_ok[i] = ego_is_vehicle(w.table)
        try:
            self._sync(ids)
        except Exception:  # noqa: BLE001 - a type the lists cannot hold: fall back for good
            # (World.move_traffic repeats _take_control and update_signals with the same results:
            # nothing has moved yet)
            self._broken = True
            self._lists = None
            return False
        rows, counts = traffic_batch_kernel(np.asarray(ids, np.int64), ctl, ego_ok, *self._lists)
        start = 0
        for k, i in enumerate(ids):
            self.worlds[i]._respawn = rows[start:start + counts[k]]
            start += counts[k]
        return True

    def step_one(self, throttle: float, steer: float, brake: float) -> bool:
        """:meth:`step` for a batch of one world whose control is taken and lane states updated
        (``World.move_traffic``): one call of 7 arguments instead of 79."""
        if self._broken:
            return False
        w = self.worlds[0]
        try:
            self._sync([0])
        except Exception:  # noqa: BLE001 - as in step
            self._broken = True
            self._lists = None
            return False
        w._respawn = traffic_one_kernel(throttle, steer, brake, ego_is_vehicle(w.table), *self._lists)
        return True
