"""Object lists: what an observer sees, as rows of ``channel.OBJECT_FIELDS`` in its own frame.

:func:`object_rows` (NumPy) is the reference and the fallback without numba;
``jit_perception.object_rows_kernel`` gives the same rows (``tests/v2x/test_jit_wire.py``).
"""

from __future__ import annotations

import numpy as np

from ..core.actors import ActorTable
from ..core.geometry import world_to_local_2d
from ..core.jit import HAVE_JIT
from .jit_perception import object_rows_kernel


def object_rows(t: ActorTable, idx: np.ndarray, origin: np.ndarray, yaw: float,
                kind: np.ndarray | None = None) -> np.ndarray:
    """Rows ``(K, 10)`` of ``channel.OBJECT_FIELDS`` for actors ``idx``, in the frame at
    ``origin (2,)`` / ``yaw``, sorted by distance; class ids from ``kind`` (default
    ``t.kind``; observations pass ``World.object_classes()``)."""
    if len(idx) == 0:
        return np.zeros((0, 10), np.float32)
    kind = t.kind if kind is None else kind
    if HAVE_JIT:
        return object_rows_kernel(np.asarray(idx, np.int64), t.pos, t.yaw, t.speed, kind, t.length, t.width,
                                  t.height, t.actor_id, float(origin[0]), float(origin[1]), float(yaw))
    local = world_to_local_2d(t.pos[idx], origin, yaw)
    order = np.argsort(np.linalg.norm(local, axis=1))
    idx, local = idx[order], local[order]
    vel = world_to_local_2d(t.velocity()[idx], np.zeros(2), yaw)
    rel_yaw = (t.yaw[idx] - yaw + np.pi) % (2 * np.pi) - np.pi
    return np.stack([kind[idx], local[:, 0], local[:, 1], rel_yaw, t.length[idx], t.width[idx],
                     t.height[idx], vel[:, 0], vel[:, 1], t.actor_id[idx]], -1).astype(np.float32)


__all__ = ["object_rows"]
