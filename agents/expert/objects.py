"""The object list the planner works on, and where it comes from.

One :class:`Objects` instance holds ``K`` objects in the **world frame** as parallel arrays. The
privileged expert fills it from the actor table (every active actor but the ego); the restricted
oracles fill it from what the ego sees now, a short memory of what it saw, and (for the V2X
oracle) the objects received from the RSU over the channel.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
from v2xbench.envs.v2x_intersection.core.actors import PARKED, STATIC
from v2xbench.envs.v2x_intersection.core.classes import (
    EMERGENCY_VEHICLE,
    LARGE_VEHICLE,
    STATIC_OBSTACLE,
    TRAFFIC_CONE,
    TRAFFIC_LIGHT,
    TRAFFIC_SIGN,
)
from v2xbench.envs.v2x_intersection.core.geometry import local_to_world_2d, stack_xy

#: classes that never move (road furniture and debris)
STATIC_CLASSES = np.array([TRAFFIC_LIGHT, TRAFFIC_SIGN, TRAFFIC_CONE, STATIC_OBSTACLE])
_STATIC_KIND = np.zeros(64, bool)
_STATIC_KIND[STATIC_CLASSES] = True
_STATIC_BEHAVIOUR = np.zeros(64, bool)
_STATIC_BEHAVIOUR[[PARKED, STATIC]] = True


@dataclass
class Objects:
    """``K`` objects in the world frame (all arrays have first dimension ``K``).

    Attributes:
        kind: class ids (``classes``).
        pos: ``(K, 2)`` box centres (m).
        yaw: headings (rad).
        vel: ``(K, 2)`` velocities (m/s).
        accel: longitudinal accelerations along ``yaw`` (m/s^2; 0 where unknown).
        length, width: box extents (m).
        static: known never to move (parked vehicle, cone, debris, barrier).
        emergency: an emergency vehicle with its lights on.
        ids: actor ids (-1 where unknown, e.g. objects received over V2X).
    """

    kind: np.ndarray
    pos: np.ndarray
    yaw: np.ndarray
    vel: np.ndarray
    accel: np.ndarray
    length: np.ndarray
    width: np.ndarray
    static: np.ndarray
    emergency: np.ndarray
    ids: np.ndarray

    @classmethod
    def empty(cls) -> Objects:
        """No objects."""
        z = np.zeros(0)
        return cls(
            np.zeros(0, np.int64),
            np.zeros((0, 2)),
            z,
            np.zeros((0, 2)),
            z,
            z,
            z,
            np.zeros(0, bool),
            np.zeros(0, bool),
            np.zeros(0, np.int64),
        )

    def __len__(self) -> int:
        return len(self.kind)

    @property
    def speed(self) -> np.ndarray:
        """``(K,)`` speed (m/s)."""
        return np.hypot(self.vel[:, 0], self.vel[:, 1])

    def take(self, idx: np.ndarray) -> Objects:
        """The subset ``idx`` (indices or boolean mask)."""
        return Objects(*(getattr(self, name)[idx] for name in _FIELDS))

    @staticmethod
    def concat(parts: list[Objects]) -> Objects:
        """Concatenate object lists."""
        parts = [p for p in parts if len(p)]
        if not parts:
            return Objects.empty()
        return Objects(
            **{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Objects)}
        )


#: ``Objects``' field names in order (``dataclasses.fields`` costs ~2 us a call)
_FIELDS = tuple(f.name for f in fields(Objects))


def from_table(t, rows: np.ndarray, emergency_rows=()) -> Objects:
    """Objects for actor-table ``rows`` (world frame).

    Actors held in place by their scenario (``hold``) stand still whatever speed they carry.
    """
    rows = np.asarray(rows, np.int64)
    speed = np.where(t.hold[rows], 0.0, t.speed[rows])
    yaw = t.yaw[rows]
    vel = speed[:, None] * stack_xy(np.cos(yaw), np.sin(yaw))
    static = _STATIC_BEHAVIOUR[t.behaviour[rows]] | _STATIC_KIND[t.kind[rows]]
    emergency = np.zeros(len(rows), bool)
    if len(emergency_rows):
        emergency = np.isin(rows, np.asarray(emergency_rows, np.int64))
    return Objects(
        kind=t.kind[rows].astype(np.int64),
        pos=t.pos[rows].copy(),
        yaw=yaw.copy(),
        vel=vel,
        accel=np.where(t.hold[rows], 0.0, t.accel[rows]),
        length=t.length[rows].copy(),
        width=t.width[rows].copy(),
        static=static,
        emergency=emergency,
        ids=t.actor_id[rows].astype(np.int64),
    )


def from_observation_rows(rows: np.ndarray, ego_xy: np.ndarray, ego_yaw: float) -> Objects:
    """Objects from observation rows ``(M, 11)`` (``observations.OBJECT_FEATURES``, ego frame).

    Rows with ``present == 0`` are dropped; ids are unknown (-1); static road furniture is
    recognized by class; an emergency vehicle (class ``EMERGENCY_VEHICLE``) becomes a large
    vehicle flagged ``emergency``, as :func:`from_table` gives it.
    """
    rows = np.asarray(rows, np.float64)
    rows = rows[rows[:, 0] > 0.5]
    if len(rows) == 0:
        return Objects.empty()
    kind = rows[:, 1].astype(np.int64)
    emergency = kind == EMERGENCY_VEHICLE
    kind[emergency] = LARGE_VEHICLE
    pos = local_to_world_2d(rows[:, 2:4], np.asarray(ego_xy, float), ego_yaw)
    c, s = np.cos(ego_yaw), np.sin(ego_yaw)
    vel = stack_xy(c * rows[:, 8] - s * rows[:, 9], s * rows[:, 8] + c * rows[:, 9])
    n = len(rows)
    return Objects(
        kind=kind,
        pos=pos,
        yaw=rows[:, 4] + ego_yaw,
        vel=vel,
        accel=np.zeros(n),
        length=rows[:, 5],
        width=rows[:, 6],
        static=_STATIC_KIND[kind.clip(0, 63)],
        emergency=emergency,
        ids=np.full(n, -1, np.int64),
    )


def moved_to(objs: Objects, times: np.ndarray, time_s: float) -> Objects:
    """A copy of ``objs`` (seen at ``times``, s) moved along their velocities to ``time_s``."""
    moved = objs.take(np.arange(len(objs)))
    moved.pos = objs.pos + objs.vel * (time_s - times)[:, None]
    return moved


class ObjectMemory:
    """Keeps objects seen in the last ``horizon_s`` seconds, propagated at constant velocity.

    Args:
        horizon_s: how long an object that is no longer seen is remembered (s).
    """

    def __init__(self, horizon_s: float = 2.0) -> None:
        self.horizon_s = horizon_s
        self.reset()

    def reset(self) -> None:
        """Forget everything."""
        self._objs = Objects.empty()
        self._time = np.zeros(0)

    def update(self, seen: Objects, time_s: float) -> Objects:
        """Store ``seen`` (objects with ids) and return it plus remembered, unseen objects, moved
        along their last velocity."""
        return Objects.concat(list(self.update_split(seen, time_s)))

    def update_split(self, seen: Objects, time_s: float) -> tuple[Objects, Objects]:
        """As :meth:`update`, returning ``(seen, remembered)`` apart (so that fresher sources can
        take precedence over remembered objects)."""
        keep = ~np.isin(self._objs.ids, seen.ids) & (time_s - self._time <= self.horizon_s)
        old, t_old = self._objs.take(keep), self._time[keep]
        self._objs = Objects.concat([seen, old])
        self._time = np.concatenate([np.full(len(seen), time_s), t_old])
        if len(old) == 0:
            return seen, old
        return seen, moved_to(old, t_old, time_s)


class AnonymousMemory:
    """:class:`ObjectMemory` for objects without ids (those received over V2X): a remembered
    object is the same as a fresh one within ``radius`` m of where it would be now.

    Args:
        horizon_s: how long an object that is no longer received is remembered (s).
        radius: match distance (m).
    """

    def __init__(self, horizon_s: float = 2.0, radius: float = 2.0) -> None:
        self.horizon_s, self.radius = horizon_s, radius
        self.reset()

    def reset(self) -> None:
        """Forget everything."""
        self._objs = Objects.empty()
        self._time = np.zeros(0)

    def update(self, seen: Objects, time_s: float) -> Objects:
        """Store ``seen`` and return it plus the remembered objects that no fresh one matches,
        moved along their last velocity."""
        live = time_s - self._time <= self.horizon_s
        old, t_old = self._objs.take(live), self._time[live]  # positions at their own time
        moved = moved_to(old, t_old, time_s)
        keep = np.ones(len(old), bool)
        if len(old) and len(seen):
            d = np.linalg.norm(moved.pos[:, None, :] - seen.pos[None, :, :], axis=-1).min(1)
            keep = d > self.radius
        self._objs = Objects.concat([seen, old.take(keep)])
        self._time = np.concatenate([np.full(len(seen), time_s), t_old[keep]])
        return Objects.concat([seen, moved.take(keep)])


def dedupe(primary: Objects, extra: Objects, radius: float = 2.0) -> Objects:
    """``primary`` plus the objects of ``extra`` farther than ``radius`` m from all of its members."""
    if len(extra) == 0:
        return primary
    if len(primary) == 0:
        return extra
    d = np.linalg.norm(extra.pos[:, None, :] - primary.pos[None, :, :], axis=-1)
    return Objects.concat([primary, extra.take(d.min(1) > radius)])
