"""numba kernel for the ego observation of ``objects`` mode (``observations.ego_observation``).

One call fills the ego vector, the route window, the visible objects, and the received V2X
objects with their info vector, writing into the caller's arrays (fresh ones for a single env,
rows of the batch buffers for ``batch.WorldBatch``). The operations are those of the NumPy path,
in the same order and dtype, so both give the same bytes (``tests/core/test_jit.py``).
"""

from __future__ import annotations

import numpy as np

from ..core.jit import _njit, project_kernel
from ..perception.jit_perception import route_window_kernel, v2x_rows_kernel, visible_objects_kernel


@_njit
def ego_obs_kernel(ego_out, route_out, objects_out, v2x_out, info_out, with_objects, route_points, commands, k0,
                   route_step, vis, threshold, pos, yaw, speed, accel, kind, length, width, height, actor_id, lane,
                   stop_at_end, lane_length, setback, points, owner, offset, n_points, gs, base, has_msg, payload, rx,
                   ry, ryaw, age, control, applied_steer, max_steer, wheelbase, lane_signal, stop_sign_lane,
                   light_stop_sign, route_completion):  # pragma: no cover
    """Fill ``ego_out (9,)`` (``observations.EGO_FEATURES``: the light of route lane ``lane``, its
    stop sign where ``stop_sign_lane``, the distance to its stop line, the ego's last ``control``
    (the agent's command) and the yaw rate of the steer its dynamics applied, ``applied_steer``),
    ``route_out (P, 3)``, ``objects_out (M, 11)`` (when ``with_objects``), ``v2x_out (M, 11)`` and
    ``info_out (6,)`` (zeros unless ``has_msg``: the ``payload`` sent by the unit at
    ``(rx, ry, ryaw)`` ``age`` ticks ago) for the ego in row 0.

    Returns:
        the distance (m) along route lane ``lane`` to its stop line (-1 where it has none).
    """
    ex, ey, eyaw = pos[0, 0], pos[0, 1], yaw[0]
    route_window_kernel(route_out, route_points, commands, k0, route_step, ex, ey, eyaw)
    if with_objects:
        visible_objects_kernel(objects_out, vis, threshold, pos, yaw, speed, kind, length, width, height, actor_id, ex,
                               ey, eyaw)
    if has_msg:
        n_rows = payload.shape[0] // 10
        v2x_rows_kernel(v2x_out, payload, n_rows, rx, ry, ryaw, ex, ey, eyaw)
        c, s = np.cos(eyaw), np.sin(eyaw)  # the unit in the ego frame (world_to_local_2d's operations)
        d0, d1 = rx - ex, ry - ey
        info_out[0] = 1.0
        info_out[1] = age
        info_out[2] = n_rows
        info_out[3] = c * d0 + s * d1
        info_out[4] = -s * d0 + c * d1
        info_out[5] = (ryaw - eyaw + np.pi) % (2.0 * np.pi) - np.pi
    else:
        v2x_out[:] = 0.0
        info_out[:] = 0.0
    dist_line = -1.0
    if stop_at_end[lane]:
        q = np.empty((1, 2))
        q[0, 0], q[0, 1] = ex, ey
        _, s_lane, _ = project_kernel(q, points, np.arange(offset[lane], offset[lane] + n_points[lane]), owner,
                                      offset, n_points, gs, base)
        dist_line = lane_length[lane] - setback - s_lane[0]
    light = np.float64(lane_signal[lane])
    if light < 0 and stop_sign_lane[lane]:
        light = np.float64(light_stop_sign)
    sp = speed[0]
    ego_out[0] = sp
    ego_out[1] = accel[0]
    ego_out[2] = sp * np.tan(applied_steer * max_steer) / wheelbase  # yaw rate
    ego_out[3], ego_out[4], ego_out[5] = control[0], control[1], control[2]
    ego_out[6] = light
    ego_out[7] = dist_line
    ego_out[8] = route_completion
    return dist_line


@_njit
def ego_obs_packed_kernel(ego_out, route_out, objects_out, v2x_out, info_out, with_objects, k0, vis, lane, has_msg,
                         payload, rx, ry, ryaw, age, control, applied_steer, lane_signal, route_completion,
                         consts):  # pragma: no cover
    """:func:`ego_obs_kernel` with the arguments that hold for an episode in ``consts[0]``
    (``observations.fill_objects_observation``, :class:`~.jit_args.PackedArgs`): ``(route_points,
    commands, route_step, threshold, pos, yaw, speed, accel, kind, length, width, height, actor_id,
    stop_at_end, lane_length, setback, points, owner, offset, n_points, gs, base, max_steer,
    wheelbase, stop_sign_lane, light_stop_sign)``."""
    c = consts[0]
    return ego_obs_kernel(ego_out, route_out, objects_out, v2x_out, info_out, with_objects, c[0], c[1], k0, c[2], vis,
                          c[3], c[4], c[5], c[6], c[7], c[8], c[9], c[10], c[11], c[12], lane, c[13], c[14], c[15],
                          c[16], c[17], c[18], c[19], c[20], c[21], has_msg, payload, rx, ry, ryaw, age, control,
                          applied_steer, c[22], c[23], lane_signal, c[24], c[25], route_completion)
