"""The traffic's move (``World.move_traffic``) and perception (``World.perceive``) of many worlds,
each in one numba call.

Called once per world, ``jit_tick.traffic_tick_kernel`` costs ~10 us of numba's dispatch alone
(79 arguments to type and unbox; ``perceive_all_kernel`` takes 31). :class:`ArgLists` keeps each
world's arguments in numba typed lists, refreshed only when they change (a reset, a new lane-state
array, a new plan), and :func:`traffic_batch_kernel` / :func:`perceive_batch_kernel` call the same
kernels world after world, so a batch pays one dispatch per tick and stage
(:class:`TrafficBatch`, :class:`PerceiveBatch`). A single world uses a batch of one:
:func:`traffic_one_kernel` takes 9 arguments (one typed list, the lane states and plans as
arrays), :func:`perceive_one_kernel` 1. Each world sees exactly the call it would make alone
(``tests/sim/test_jit_batch.py`` and ``tests/api/test_batch.py`` compare, byte for byte).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..core.jit import _njit
from ..core.jit_args import List, ListOf, list_append, list_set, new_list  # noqa: F401 (re-exported)
from ..perception.jit_perception import perceive_all_kernel
from ..traffic.pedestrians import ego_is_vehicle
from ..traffic.vehicles import flat_plans
from .jit_tick import traffic_tick_kernel


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
def traffic_one_kernel(throttle, steer, brake, ego_ok, consts, signals, plan_lanes, plan_start,
                       plan_len):  # pragma: no cover
    """``traffic_tick_kernel`` for one world: its episode's arguments in entry 0 of the typed list
    ``consts``, the lane states and ``traffic.flat_plans`` as plain arrays (an array argument costs
    numba's dispatch ~40 ns, a typed list ~0.9 us: measured 2026-11-26)."""
    c = consts[0]
    return traffic_tick_kernel(throttle, steer, brake, c[0], signals, plan_lanes, plan_start, plan_len, c[1], ego_ok,
                               c[2], *c[3:])


class ArgLists:
    """Kernel arguments of ``N`` worlds in numba typed lists: one list per group of arguments,
    entry ``i`` for world ``i``, built on the first :meth:`sync` and then refreshed entry by entry
    when the object ``entries(world)`` gives for a group is not the one the entry was built from
    (the callers keep each group in one object for as long as it holds: a cached tuple, the
    lane-state array, ``traffic.flat_plans``' cached tuple).

    Should the worlds' arguments not share one numba type (they do for every configuration of one
    batch), :meth:`sync` returns ``False`` from then on and the caller calls its kernel per world.
    """

    def __init__(self, worlds: list, entries: Callable[[object], tuple]) -> None:
        self.worlds = worlds
        self.entries = entries
        self.lists: tuple | None = None
        self._keys: list[list] = []  # per group, the object each entry was built from
        self.broken = False

    def sync(self, ids) -> bool:
        """Refresh the entries of worlds ``ids``; ``False``: the lists cannot be used."""
        if self.broken:
            return False
        try:
            if self.lists is None:
                rows = [self.entries(w) for w in self.worlds]
                lists = tuple(new_list(x) for x in rows[0])
                for row in rows[1:]:
                    for lst, x in zip(lists, row):
                        list_append(lst, x)
                self.lists = lists
                self._keys = [[row[j] for row in rows] for j in range(len(lists))]
                return True
            for i in ids:
                for j, x in enumerate(self.entries(self.worlds[i])):
                    if x is not self._keys[j][i]:
                        list_set(self.lists[j], i, x)
                        self._keys[j][i] = x
        except Exception:  # noqa: BLE001 - a type the lists cannot hold: fall back for good
            self.broken = True
            self.lists = None
            return False
        return True


def _traffic_entries(w) -> tuple:
    return w._traffic_consts(), w.lane_signal, flat_plans(w.plans)


class TrafficBatch:
    """``World.move_traffic`` for the worlds of a batch in one kernel call (numba only), through
    :class:`ArgLists` (groups: the episode's arguments, the lane states, the plans)."""

    def __init__(self, worlds: list) -> None:
        self.worlds = worlds
        self.args = ArgLists(worlds, _traffic_entries)
        self.one = ListOf()  # (step_one)

    def step(self, ids: list[int], controls: np.ndarray) -> bool:
        """Move worlds ``ids`` under ``controls[i]`` (checked ``(N, 3)``); ``False``: not done,
        move them one by one (``World.move_traffic`` then repeats the control bookkeeping and the
        lane-state update with the same results: nothing has moved yet)."""
        if self.args.broken or any(getattr(w, "table", None) is None for w in self.worlds):
            return False
        n = len(self.worlds)
        ctl = np.zeros((n, 3))
        ego_ok = np.zeros(n, np.bool_)
        for i in ids:
            w = self.worlds[i]
            ctl[i] = w._take_control(controls[i])
            w.update_signals()
            ego_ok[i] = ego_is_vehicle(w.table)
        if not self.args.sync(ids):
            return False
        rows, counts = traffic_batch_kernel(np.asarray(ids, np.int64), ctl, ego_ok, *self.args.lists)
        start = 0
        for k, i in enumerate(ids):
            self.worlds[i]._respawn = rows[start:start + counts[k]]
            start += counts[k]
        return True

    def step_one(self, throttle: float, steer: float, brake: float) -> bool:
        """:meth:`step` for a batch of one world whose control is taken and lane states updated
        (``World.move_traffic``): one call of 9 arguments instead of 79."""
        w = self.worlds[0]
        consts = self.one.get(w._traffic_consts())
        if consts is None:
            return False
        w._respawn = traffic_one_kernel(throttle, steer, brake, ego_is_vehicle(w.table), consts, w.lane_signal,
                                        *flat_plans(w.plans))
        return True


@_njit
def perceive_one_kernel(consts):  # pragma: no cover
    """``jit_perception.perceive_all_kernel`` with the arguments of entry 0 of ``consts`` (its
    results land in the last three, its output arrays; nothing is returned, which saves boxing
    three arrays)."""
    perceive_all_kernel(*consts[0])


@_njit
def perceive_batch_kernel(order, consts):  # pragma: no cover
    """``perceive_all_kernel`` for worlds ``order`` (``consts[w]``: world ``w``'s arguments).

    Returns:
        ``(active (M, slots), vis)``: world ``order[k]``'s ``ego_vis (n,)`` then ``rsu_vis (slots,
        n)`` (row-major) follow each other in ``vis``, world after world.
    """
    m = order.shape[0]
    parts = List()
    total = 0
    slots = 0
    for k in range(m):
        r = perceive_all_kernel(*consts[order[k]])
        slots = r[0].shape[0]
        total += r[1].shape[0] + r[2].size
        parts.append(r)
    active = np.empty((m, slots), np.int64)
    vis = np.empty(total)
    j = 0
    for k in range(m):
        a, ego, rsu = parts[k]
        for q in range(slots):
            active[k, q] = a[q]
        for q in range(ego.shape[0]):
            vis[j] = ego[q]
            j += 1
        for u in range(rsu.shape[0]):
            for q in range(rsu.shape[1]):
                vis[j] = rsu[u, q]
                j += 1
    return active, vis


def _perceive_entries(w) -> tuple:
    return (w._perceive_consts(),)


class PerceiveBatch:
    """``World.perceive`` for the worlds of a batch in one kernel call (numba only), through
    :class:`ArgLists` (one group: the episode's arguments; perception has no others)."""

    def __init__(self, worlds: list) -> None:
        self.worlds = worlds
        self.args = ArgLists(worlds, _perceive_entries)
        self.one = ListOf()  # (step_one)

    def step(self, ids: list[int]) -> bool:
        """Perceive in worlds ``ids``; ``False``: not done, call ``World.perceive`` per world."""
        if not self.args.sync(ids):
            return False
        active, vis = perceive_batch_kernel(np.asarray(ids, np.int64), *self.args.lists)
        j = 0
        for k, i in enumerate(ids):
            w = self.worlds[i]
            n, slots = len(w.table), active.shape[1]
            w.active_rsu = active[k]
            w.ego_vis = vis[j:j + n]
            w.rsu_vis = vis[j + n:j + n + slots * n].reshape(slots, n)
            j += n + slots * n
        return True

    def step_one(self) -> bool:
        """:meth:`step` for a batch of one world: one argument instead of 31."""
        w = self.worlds[0]
        args = w._perceive_consts()
        consts = self.one.get(args)
        if consts is None:
            return False
        perceive_one_kernel(consts)
        w.active_rsu, w.ego_vis, w.rsu_vis = args[-3:]
        return True
