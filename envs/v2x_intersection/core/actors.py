"""The actor table: every dynamic actor of a world as a struct of NumPy arrays.

Row 0 is always the ego vehicle. Rows are never reordered during an episode (so ids, indices and
pymunk shapes stay aligned); an actor that leaves is marked ``active = False``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .classes import BICYCLE, CAR, LARGE_VEHICLE, PEDESTRIAN
from .jit import HAVE_JIT, _njit
from .jit_rng import state_views, uniform

# behaviour codes
EGO, DRIVER, PARKED, WALKER, RIDER, STATIC, SCRIPTED = 0, 1, 2, 3, 4, 5, 6
BEHAVIOUR_NAMES = ("ego", "driver", "parked", "walker", "rider", "static", "scripted")
#: m, the ego's box (length, width, height)
EGO_LENGTH, EGO_WIDTH, EGO_HEIGHT = 4.7, 1.9, 1.5

#: (length, width, height) ranges per class (m)
SIZES = {
    CAR: ((4.2, 4.9), (1.8, 2.0), (1.4, 1.6)),
    LARGE_VEHICLE: ((6.0, 11.0), (2.3, 2.6), (2.8, 3.8)),
    PEDESTRIAN: ((0.5, 0.6), (0.5, 0.6), (1.6, 1.9)),
    BICYCLE: ((1.7, 1.8), (0.6, 0.7), (1.6, 1.8)),
}
#: share of pedestrians who are children (of every walker, background or scenario)
CHILD_SHARE = 0.15
CHILD_FOOTPRINT = (0.35, 0.45)  # m, a child's box length and width range
CHILD_HEIGHT = (1.0, 1.35)  # m, a child's height range (hidden behind a parked car)


@dataclass
class ActorTable:
    """Struct-of-arrays state of ``N`` actors (shapes ``(N,)`` unless noted).

    Attributes:
        kind: class id (``classes``). behaviour: ``EGO | DRIVER | PARKED | WALKER | RIDER | STATIC |
            SCRIPTED`` (scripted actors are moved by their scenario, not by the world).
        actor_id: unique id within the episode. active: present in the world.
        pos: ``(N, 2)`` box centre (m). yaw (rad). speed (m/s, along yaw). accel (m/s^2).
        length, width, height: box size (m).
        lane, s: lane id and arc length (m) for lane followers (-1 / 0 otherwise).
        lat: lateral offset from the lane centre (m, left positive; decays after lane changes).
        v0: desired speed (m/s). wait: seconds stopped (for stop signs and deadlock release).
        stopped_at_sign: has made its full stop at the stop line of its current lane.
        path, path_s, path_dir: for pedestrians: sidewalk id (or -1 while crossing), arc length, +-1.
        cross_from, cross_to: ``(N, 2)`` straight crossing segment for crossing pedestrians (m).
        color: ``(N,)`` colour index for rendering.
        hold: the actor waits in place (scenario actors before their trigger).
        ignore_rules: a follower that ignores lights, stop signs and junction yielding.
        plan: index into ``World.plans`` (a fixed lane sequence to follow; -1: random successors).
        plan_pos: position of the current lane in that plan.
        scenario: index of the scenario owning the actor (-1: background traffic).
    """

    kind: np.ndarray
    behaviour: np.ndarray
    actor_id: np.ndarray
    active: np.ndarray
    pos: np.ndarray
    yaw: np.ndarray
    speed: np.ndarray
    accel: np.ndarray
    length: np.ndarray
    width: np.ndarray
    height: np.ndarray
    lane: np.ndarray
    s: np.ndarray
    lat: np.ndarray
    v0: np.ndarray
    wait: np.ndarray
    stopped_at_sign: np.ndarray
    path: np.ndarray
    path_s: np.ndarray
    path_dir: np.ndarray
    cross_from: np.ndarray
    cross_to: np.ndarray
    color: np.ndarray
    hold: np.ndarray
    ignore_rules: np.ndarray
    plan: np.ndarray
    plan_pos: np.ndarray
    scenario: np.ndarray

    @classmethod
    def empty(cls, n: int) -> ActorTable:
        """A table of ``n`` inactive rows."""
        f = np.zeros
        return cls(
            kind=f(n, np.int64), behaviour=f(n, np.int64), actor_id=np.arange(n, dtype=np.int64),
            active=f(n, bool), pos=f((n, 2)), yaw=f(n), speed=f(n), accel=f(n), length=f(n),
            width=f(n), height=f(n), lane=np.full(n, -1, np.int64), s=f(n), lat=f(n), v0=f(n),
            wait=f(n), stopped_at_sign=f(n, bool), path=np.full(n, -1, np.int64), path_s=f(n),
            path_dir=np.ones(n), cross_from=f((n, 2)), cross_to=f((n, 2)), color=f(n, np.int64),
            hold=f(n, bool), ignore_rules=f(n, bool), plan=np.full(n, -1, np.int64),
            plan_pos=f(n, np.int64), scenario=np.full(n, -1, np.int64),
        )

    def __len__(self) -> int:
        return len(self.kind)

    def copy(self) -> ActorTable:
        """Deep copy (arrays copied)."""
        return ActorTable(**{f.name: getattr(self, f.name).copy() for f in fields(self)})

    def velocity(self) -> np.ndarray:
        """``(N, 2)`` world-frame velocity (m/s)."""
        return self.speed[:, None] * np.stack([np.cos(self.yaw), np.sin(self.yaw)], -1)


def draw_size(kind: int, rng: np.random.Generator) -> tuple[float, float, float]:
    """Random ``(length, width, height)`` for a class (m): three ``rng.uniform`` draws in order
    (a pedestrian's draw becomes a child's box in :data:`CHILD_SHARE` of the cases, see
    :func:`pedestrian_size`)."""
    (l0, l1, l2), (h0, h1, h2) = _SIZE_FLOATS[kind]
    if HAVE_JIT and type(rng.bit_generator) is np.random.PCG64:  # the generator's own draws in a kernel
        # (a scalar uniform() call costs ~4 us; jit_rng replicates PCG64, what default_rng makes)
        words, _ = state_views(rng)
        size = uniform3_kernel(words, l0, l1, l2, h0, h1, h2)
    else:
        u = rng.uniform
        size = u(l0, h0), u(l1, h1), u(l2, h2)
    if kind == PEDESTRIAN:
        return tuple(float(v) for v in pedestrian_size(*size))
    return size


def child_size(length, width, height):
    """A child's box (m) from a pedestrian's size draw (any draw in ``SIZES[PEDESTRIAN]``, scalars
    or arrays): footprint :data:`CHILD_FOOTPRINT`, height :data:`CHILD_HEIGHT`, each at the same
    relative place in its range as the draw. No new random draws: the generator's stream stays
    as it was."""
    (l0, l1), (w0, w1), (h0, h1) = SIZES[PEDESTRIAN]
    (c0, c1), (k0, k1) = CHILD_FOOTPRINT, CHILD_HEIGHT
    fl = np.clip((np.asarray(length, float) - l0) / (l1 - l0), 0.0, 1.0)
    fw = np.clip((np.asarray(width, float) - w0) / (w1 - w0), 0.0, 1.0)
    fh = np.clip((np.asarray(height, float) - h0) / (h1 - h0), 0.0, 1.0)
    return c0 + fl * (c1 - c0), c0 + fw * (c1 - c0), k0 + fh * (k1 - k0)


def pedestrian_size(length, width, height):
    """A pedestrian's box from its size draw: a child's (:func:`child_size`) when the length draw
    lies in the lowest :data:`CHILD_SHARE` of its range (background walkers and scenario walkers
    alike, so a small walker says nothing about a scenario), else the draw itself."""
    (l0, l1), _, _ = SIZES[PEDESTRIAN]
    length, width, height = (np.asarray(v, float) for v in (length, width, height))
    child = length < l0 + CHILD_SHARE * (l1 - l0)
    cl, cw, ch = child_size(length, width, height)
    return np.where(child, cl, length), np.where(child, cw, width), np.where(child, ch, height)


@_njit
def uniform3_kernel(words, l0, l1, l2, h0, h1, h2):  # pragma: no cover
    """``(rng.uniform(l0, h0), rng.uniform(l1, h1), rng.uniform(l2, h2))`` on ``jit_rng``'s view of
    the generator's state."""
    a = uniform(words, l0, h0)
    b = uniform(words, l1, h1)
    return a, b, uniform(words, l2, h2)


#: per class, ``(low (3,), high (3,))`` of :data:`SIZES`
SIZE_BOUNDS = {k: (np.array([r[0] for r in v]), np.array([r[1] for r in v])) for k, v in SIZES.items()}
_SIZE_FLOATS = {k: (tuple(r[0] for r in v), tuple(r[1] for r in v)) for k, v in SIZES.items()}
