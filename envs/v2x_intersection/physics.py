"""Collision detection with pymunk (Chipmunk2D).

Every actor and static box has a shape in one ``pymunk.Space``. Kinematic bodies produce no
contact callbacks between each other in Chipmunk, so we *query*: each tick the ego's shape is
tested with ``space.shape_query`` against the shapes near it (a NumPy broad phase picks which
bodies to move before the query, keeping the tick cheap).
"""

from __future__ import annotations

import numpy as np
import pymunk

from .actors import ActorTable
from .geometry import row_norms


class CollisionWorld:
    """pymunk space mirroring the actor table (row ``i`` <-> ``bodies[i]``) and static boxes."""

    def __init__(self, table: ActorTable, statics: np.ndarray) -> None:
        """Args:
        table: actor table (sizes read once; rows keep their size for the episode).
        statics: ``(S, 5)`` static boxes ``(x, y, length, width, yaw)`` (buildings, poles).
        """
        self.space = pymunk.Space()
        self.bodies: list[pymunk.Body] = []
        self.shapes: list[pymunk.Shape] = []
        self.shape_owner: dict[pymunk.Shape, int] = {}
        for i in range(len(table)):
            body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            shape = pymunk.Poly.create_box(body, (float(table.length[i]), float(table.width[i])))
            shape.sensor = True
            self.space.add(body, shape)
            self.bodies.append(body)
            self.shapes.append(shape)
            self.shape_owner[shape] = i
        self.num_actors = len(table)
        for k, (x, y, length, width, yaw) in enumerate(np.asarray(statics, float).reshape(-1, 5)):
            c, s = np.cos(yaw), np.sin(yaw)
            hl, hw = length / 2, width / 2
            verts = [(x + c * a - s * b, y + s * a + c * b) for a, b in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))]
            shape = pymunk.Poly(self.space.static_body, verts)
            shape.sensor = True
            self.space.add(shape)
            self.shape_owner[shape] = -1 - k  # statics: negative ids
        self._radius = 0.5 * np.hypot(table.length, table.width)

    def ego_contacts(self, table: ActorTable, static_radius: float = 60.0) -> np.ndarray:
        """Indices of actors (>= 1) and statics (encoded ``-1 - k``) in contact with the ego."""
        near = row_norms(table.pos - table.pos[0]) < self._radius + self._radius[0] + 0.5
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
