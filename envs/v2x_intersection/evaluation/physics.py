"""Collision detection: which actors and static boxes touch the ego.

Two implementations answer the same query, :meth:`CollisionWorld.ego_contacts`:

- the default, an exact separating-axis test of the ego's box against every nearby box, compiled
  with numba (:func:`ego_contacts_kernel`); it reads the actor table directly, so a reset costs
  nothing here;
- the reference (``V2XBENCH_NO_JIT=1``, and the cross-check in the tests), a pymunk ``Space``
  with one kinematic shape per actor and one static shape per box, queried with
  ``space.shape_query`` (kinematic-kinematic pairs produce no contact callbacks in Chipmunk, so
  we query rather than wait for callbacks).

Both count touching boxes as a contact. They can disagree only when two boxes are within float
rounding of touching. The space is built lazily, on the first query of the reference path:
building it costs about 20 ms per reset, and pymunk keeps removed bodies alive, so a reused
space leaks memory.
"""

from __future__ import annotations

import numpy as np

from ..core.actors import ActorTable
from ..core.geometry import row_norms
from ..core.jit import HAVE_JIT, _njit

CONTACT_MARGIN = 0.5  # m, added to the bounding circles of the broad phase (both paths)


@_njit
def _boxes_touch(ax, ay, ac, as_, ahl, ahw, bx, by, bc, bs, bhl, bhw):  # pragma: no cover
    """Whether two oriented boxes overlap or touch (separating-axis test on their four axes)."""
    dx, dy = bx - ax, by - ay
    for k in range(4):
        if k == 0:
            nx, ny = ac, as_
        elif k == 1:
            nx, ny = -as_, ac
        elif k == 2:
            nx, ny = bc, bs
        else:
            nx, ny = -bs, bc
        ra = ahl * abs(ac * nx + as_ * ny) + ahw * abs(-as_ * nx + ac * ny)
        rb = bhl * abs(bc * nx + bs * ny) + bhw * abs(-bs * nx + bc * ny)
        if abs(dx * nx + dy * ny) > ra + rb:
            return False
    return True


@_njit
def ego_contacts_kernel(pos, yaw, length, width, active, statics, static_cos, static_sin,
                        static_radius):  # pragma: no cover
    """Rows (>= 1) and statics (``-1 - k``) whose box touches the ego's (row 0), sorted.

    Args:
        pos, yaw, length, width, active: the actor table's arrays. statics: ``(S, 5)`` boxes
            ``(x, y, length, width, yaw)``; static_cos, static_sin: their yaw's cosine and sine;
            static_radius: ``(S,)`` half diagonals.
    """
    n = pos.shape[0]
    ex, ey = pos[0, 0], pos[0, 1]
    ec, es = np.cos(yaw[0]), np.sin(yaw[0])
    ehl, ehw = 0.5 * length[0], 0.5 * width[0]
    er = 0.5 * np.sqrt(length[0] * length[0] + width[0] * width[0])
    out = np.empty(n + statics.shape[0], np.int64)
    cnt = 0
    for k in range(statics.shape[0] - 1, -1, -1):
        dx, dy = statics[k, 0] - ex, statics[k, 1] - ey
        reach = er + static_radius[k] + CONTACT_MARGIN
        if dx * dx + dy * dy >= reach * reach:
            continue
        if _boxes_touch(ex, ey, ec, es, ehl, ehw, statics[k, 0], statics[k, 1], static_cos[k], static_sin[k],
                        0.5 * statics[k, 2], 0.5 * statics[k, 3]):
            out[cnt] = -1 - k
            cnt += 1
    for i in range(1, n):
        if not active[i]:
            continue
        dx, dy = pos[i, 0] - ex, pos[i, 1] - ey
        reach = er + 0.5 * np.sqrt(length[i] * length[i] + width[i] * width[i]) + CONTACT_MARGIN
        if dx * dx + dy * dy >= reach * reach:
            continue
        if _boxes_touch(ex, ey, ec, es, ehl, ehw, pos[i, 0], pos[i, 1], np.cos(yaw[i]), np.sin(yaw[i]),
                        0.5 * length[i], 0.5 * width[i]):
            out[cnt] = i
            cnt += 1
    return out[:cnt].copy()


class CollisionWorld:
    """Contact queries for one episode: the static boxes, and the actor table passed per query."""

    def __init__(self, table: ActorTable, statics: np.ndarray) -> None:
        """Args:
        table: actor table (the reference path reads box sizes from it once; rows keep their size
            for the episode).
        statics: ``(S, 5)`` static boxes ``(x, y, length, width, yaw)`` (buildings, poles).
        """
        self.statics = np.ascontiguousarray(np.asarray(statics, float).reshape(-1, 5))
        self._cos, self._sin = np.cos(self.statics[:, 4]), np.sin(self.statics[:, 4])
        self._static_radius = 0.5 * np.hypot(self.statics[:, 2], self.statics[:, 3])
        self._sizes = (table.length.copy(), table.width.copy())
        self._space: PymunkWorld | None = None

    def kernel_args(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``ego_contacts_kernel``'s static arguments: the boxes, their yaw's cosine and sine, their
        half diagonals."""
        return self.statics, self._cos, self._sin, self._static_radius

    def ego_contacts(self, table: ActorTable) -> np.ndarray:
        """Indices of actors (>= 1) and statics (encoded ``-1 - k``) in contact with the ego, sorted."""
        if HAVE_JIT:
            return ego_contacts_kernel(table.pos, table.yaw, table.length, table.width, table.active,
                                       *self.kernel_args())
        if self._space is None:
            self._space = PymunkWorld(*self._sizes, self.statics)
        return self._space.ego_contacts(table)


class PymunkWorld:
    """pymunk space mirroring the actor table (row ``i`` <-> ``bodies[i]``) and the static boxes."""

    def __init__(self, length: np.ndarray, width: np.ndarray, statics: np.ndarray) -> None:
        import pymunk

        self.space = pymunk.Space()
        self.bodies: list = []
        self.shapes: list = []
        self.shape_owner: dict = {}
        for i in range(len(length)):
            body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            shape = pymunk.Poly.create_box(body, (float(length[i]), float(width[i])))
            shape.sensor = True
            self.space.add(body, shape)
            self.bodies.append(body)
            self.shapes.append(shape)
            self.shape_owner[shape] = i
        for k, (x, y, lk, wk, yaw) in enumerate(statics):
            c, s = np.cos(yaw), np.sin(yaw)
            hl, hw = lk / 2, wk / 2
            verts = [(x + c * a - s * b, y + s * a + c * b) for a, b in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))]
            shape = pymunk.Poly(self.space.static_body, verts)
            shape.sensor = True
            self.space.add(shape)
            self.shape_owner[shape] = -1 - k  # statics: negative ids
        self._radius = 0.5 * np.hypot(length, width)

    def ego_contacts(self, table: ActorTable) -> np.ndarray:
        """As :meth:`CollisionWorld.ego_contacts`: a NumPy broad phase picks the bodies to move,
        then one ``shape_query`` of the ego's shape."""
        near = row_norms(table.pos - table.pos[0]) < self._radius + self._radius[0] + CONTACT_MARGIN
        near &= table.active
        for i in np.flatnonzero(near):
            b = self.bodies[i]
            b.position = (float(table.pos[i, 0]), float(table.pos[i, 1]))
            b.angle = float(table.yaw[i])
            self.space.reindex_shapes_for_body(b)
        hits = self.space.shape_query(self.shapes[0])
        out = [self.shape_owner[h.shape] for h in hits if self.shape_owner.get(h.shape, 0) != 0]
        out = [o for o in out if o < 0 or (o > 0 and near[o])]
        return np.array(sorted(out), np.int64)
