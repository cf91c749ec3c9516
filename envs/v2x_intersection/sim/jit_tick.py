"""The moving part of a tick in one numba call (``World.move_traffic``, steps 3-4c of
``World.step``): the ego's kinematic bicycle, NPC vehicles and bicycles, then pedestrians, under
the traffic lights' states of the tick (computed before the call by the world's signal plan,
which a user may replace).

It calls the stages' own kernels in the order ``World`` calls them without numba, so the bytes
and the random draws are the same (``tests/core/test_jit.py`` compares both paths); one call instead of
three saves the dispatch of the arguments they share and the Python between them.
"""

from __future__ import annotations

from ..core.dynamics import bicycle_step_scalar
from ..core.jit import _njit
from ..traffic.jit_vehicles import followers_tick_kernel
from ..traffic.jit_walkers import walkers_tick_kernel


@_njit
def traffic_tick_kernel(throttle, steer, brake, bike, lane_signal, plan_lanes, plan_start, plan_len, walkers, ego_ok,
                        jaywalk_p, words, buf, succ, succ_start, n_succ, active, hold, behaviour, pos, yaw, length,
                        width, speed, lane_arr, s_arr, v0_arr, stopped_at_sign, ignore_rules, wait, accel, scenario,
                        plan, plan_pos, lat_arr, speed_limit, lane_length, stop_at_end, junction_ahead, stop_lane,
                        major, jcenter, jradius, jcontrol, idm_car, idm_bike, lookahead, setback, dt, blocked_s,
                        stuck_s, left, right, kind, lane_width, change_rate, points, heading, offset, n_points, gs,
                        base, path, path_s, path_dir, cross_from, cross_to, crossings, opposite, sw_points,
                        sw_heading, sw_offset, sw_n_points, sw_gs, sw_base, sw_length, sw_owner, ped_lookahead,
                        ego_margin):  # pragma: no cover
    """Steps 3-4c of a tick, in place on the actor table's columns.

    Args:
        throttle, steer, brake: the ego's checked control. bike: ``(max_accel, max_brake, drag,
            max_speed, max_steer, wheelbase, dt)`` of ``dynamics.bicycle_step_scalar``.
        lane_signal: ``(num_lanes,)`` signal state per lane (``signals.SignalPlan.lane_states``).
        plan_lanes, plan_start, plan_len: ``traffic.flat_plans`` of ``World.plans``.
        walkers: the town has sidewalks (else the pedestrians' arguments are stand-ins).
        ego_ok: ``pedestrians.ego_is_vehicle``. jaywalk_p: jaywalking probability per tick.
        words ... base: ``traffic.followers_args``.
        path ... ego_margin: ``pedestrians.walkers_args``.

    Returns:
        the rows to respawn (``traffic.step_followers``).
    """
    x, y, yw, v, a = bicycle_step_scalar(pos[0, 0], pos[0, 1], yaw[0], speed[0], throttle, steer, brake, bike[0],
                                         bike[1], bike[2], bike[3], bike[4], bike[5], bike[6])
    pos[0, 0], pos[0, 1] = x, y
    yaw[0], speed[0], accel[0] = yw, v, a
    respawn = followers_tick_kernel(
        lane_signal, plan_lanes, plan_start, plan_len, words, buf, succ, succ_start, n_succ, active, hold, behaviour,
        pos, yaw, length, width, speed, lane_arr, s_arr, v0_arr, stopped_at_sign, ignore_rules, wait, accel, scenario,
        plan, plan_pos, lat_arr, speed_limit, lane_length, stop_at_end, junction_ahead, stop_lane, major, jcenter,
        jradius, jcontrol, idm_car, idm_bike, lookahead, setback, dt, blocked_s, stuck_s, left, right, kind,
        lane_width, change_rate, points, heading, offset, n_points, gs, base)
    if walkers:
        walkers_tick_kernel(words, buf, active, hold, behaviour, path, path_s, path_dir, speed, lat_arr, pos, yaw,
                            cross_from, cross_to, scenario, ego_ok, pos[0, 0], pos[0, 1], yaw[0],
                            length[0] / 2 + ego_margin, width[0] / 2 + ego_margin, ped_lookahead, dt, jaywalk_p,
                            crossings, opposite, sw_points, sw_heading, sw_offset, sw_n_points, sw_gs, sw_base,
                            sw_length, sw_owner)
    return respawn
