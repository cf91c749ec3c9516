"""Forward prediction of the objects around the ego over a few seconds.

Vehicles and bicycles that sit on a lane follow it through every continuation the lane graph
allows (one *hypothesis* per branch), with their current speed and acceleration, and stop at
their stop line when the rules say so *and* they behave like it (they are braking, or could
stop gently). A lane-changing vehicle's lateral offset decays as the simulator's followers do.
Pedestrians and vehicles off the lane network move at constant velocity. Static objects stay.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from v2xbench.envs.v2x_intersection.core.classes import BICYCLE, CAR, LARGE_VEHICLE
from v2xbench.envs.v2x_intersection.traffic.signals import RED, YELLOW

from .lanes import LaneMap
from .objects import Objects
from .prediction_jit import HAVE_JIT, lane_forecast_kernel

PRED_DT = 0.25  # s between predicted poses
PRED_STEPS = 16  # poses (4 s)
LAT_DECAY = 1.2  # m/s, the simulator's lane-change lateral speed
MOVING = 0.3  # m/s: slower objects are treated as standing


@dataclass
class Forecast:
    """``H`` hypotheses over ``T = PRED_STEPS`` future times ``taus``.

    Attributes:
        owner: ``(H,)`` index of the object in the object list.
        pos: ``(H, T, 2)`` predicted centres (m). dirn: ``(H, T, 2)`` unit headings.
        branch: ``(H,)`` lane-branch id (-1: constant velocity). s0: ``(H,)`` arc length on it now.
        stops: ``(H,)`` predicted to stop at the branch's stop line.
        taus: ``(T,)`` times (s).
        still_owner, still_branch, still_s0: lane hypotheses of *standing* vehicles (they stay
            put in the forecast; the junction rules consider that they may pull away).
    """

    owner: np.ndarray
    pos: np.ndarray
    dirn: np.ndarray
    branch: np.ndarray
    s0: np.ndarray
    stops: np.ndarray
    taus: np.ndarray
    still_owner: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    still_branch: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    still_s0: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __len__(self) -> int:
        return len(self.owner)


#: m/s^2: a follower needing less than this to stop at its sign is assumed to stop there; one
#: needing more is assumed to stop only if it already brakes harder than SIGN_BRAKING
SIGN_GENTLE, SIGN_BRAKING = 1.5, 0.5


def will_stop(
    lmap: LaneMap,
    branch: np.ndarray,
    s0: np.ndarray,
    v: np.ndarray,
    a: np.ndarray,
    half_len: np.ndarray,
    lane_signal: np.ndarray,
) -> np.ndarray:
    """Whether lane followers on ``branch`` at ``s0`` will stop at the branch's stop line.

    The rules must require it (red, yellow with room to stop, stop sign not yet served) and the
    follower must behave like it: it can stop at under 3 m/s^2, or it is already braking hard
    enough. A slow follower pulling away from a stop sign (accelerating) is predicted to go.
    """
    stop_s = lmap.br_stop_s[branch]
    lane = lmap.br_stop_lane[branch]
    d = stop_s - s0 - half_len
    ahead = np.isfinite(stop_s) & (d > -1.0)
    sig = np.where(lane >= 0, lane_signal[np.maximum(lane, 0)], -1)
    req = v * v / (2.0 * np.maximum(d, 0.3))
    sign = ahead & lmap.br_stop_sign[branch] & (sig < 0)
    departing = sign & (d < 4.0) & (v < 3.0) & (a > 0.2)
    rule = (sig == RED) | ((sig == YELLOW) & (req < 3.0)) | (sign & ~departing)
    behaving = (req < 3.0) | (a < -0.6 * req)
    # at a sign only (no light): a follower cruising on without braking, still far from gentle,
    # is taking priority (as the flows of the non-signalized junction scenarios)
    sign_only = sign & (sig < 0) & ~departing
    behaving &= ~sign_only | (req < SIGN_GENTLE) | (a < -SIGN_BRAKING)
    return ahead & rule & behaving


def forecast(
    objs: Objects, lmap: LaneMap, lane_signal: np.ndarray, relevant: np.ndarray
) -> Forecast:
    """Predict the ``relevant`` (boolean ``(K,)``) moving objects (see module docstring)."""
    taus = PRED_DT * np.arange(1, PRED_STEPS + 1)
    speed = objs.speed
    moving = relevant & (speed > MOVING) & ~objs.static
    lane_kind = (objs.kind == CAR) | (objs.kind == LARGE_VEHICLE) | (objs.kind == BICYCLE)
    standing = relevant & lane_kind & ~objs.static & (speed <= MOVING)
    cand = ((moving | standing) & lane_kind).nonzero()[0]
    lanes, s_l, lat_l, ok = lmap.assign(objs.pos[cand], objs.yaw[cand])
    brs = lmap.lane_branches[np.maximum(lanes, 0)]  # (C, 2, MAX_BRANCHES)
    valid = ok[:, :, None] & (brs >= 0)
    ci, si, _ = valid.nonzero()
    hyp_owner, hyp_br, hyp_s0 = cand[ci], brs[valid], s_l[ci, si]
    hyp_lat = lat_l[ci, si]
    is_still = standing[hyp_owner]
    still = (hyp_owner[is_still], hyp_br[is_still], hyp_s0[is_still])
    owner = hyp_owner[~is_still]
    on_lane = np.zeros(len(objs), bool)
    on_lane[owner] = True
    cv = (moving & ~on_lane).nonzero()[0]
    t = len(taus)
    parts_pos, parts_dir = [], []
    if len(owner):
        owner_b = owner
        br_b = hyp_br[~is_still]
        s0_b = hyp_s0[~is_still]
        args = (br_b, s0_b, hyp_lat[~is_still], speed[owner_b], objs.accel[owner_b], objs.length[owner_b],
                objs.kind[owner_b] == BICYCLE, taus)
        if HAVE_JIT:
            p, dirn, stops = lane_forecast_kernel(
                *args, LAT_DECAY, lane_signal, lmap.br_stop_s, lmap.br_stop_lane, lmap.br_stop_sign, lmap.br_n,
                lmap.br_start, lmap.br_pts, lmap.br_cos, lmap.br_sin, RED, YELLOW)
        else:
            p, dirn, stops = _lane_forecast(lmap, lane_signal, *args)
        parts_pos.append(p)
        parts_dir.append(dirn)
    else:
        owner_b = np.zeros(0, np.int64)
        br_b, s0_b, stops = owner_b.copy(), np.zeros(0), np.zeros(0, bool)
    if len(cv):
        p = objs.pos[cv][:, None, :] + objs.vel[cv][:, None, :] * taus[None, :, None]
        u = objs.vel[cv] / np.maximum(speed[cv], 1e-6)[:, None]
        parts_pos.append(p)
        parts_dir.append(np.repeat(u[:, None, :], t, axis=1))  # (np.broadcast_to cost ~15 us)
    if not parts_pos:
        return Forecast(
            np.zeros(0, np.int64),
            np.zeros((0, t, 2)),
            np.zeros((0, t, 2)),
            np.zeros(0, np.int64),
            np.zeros(0),
            np.zeros(0, bool),
            taus,
            *still,
        )
    return Forecast(
        owner=np.concatenate([owner_b, cv]),
        pos=np.concatenate(parts_pos, 0),
        dirn=np.concatenate(parts_dir, 0),
        branch=np.concatenate([br_b, np.full(len(cv), -1)]),
        s0=np.concatenate([s0_b, np.zeros(len(cv))]),
        stops=np.concatenate([stops, np.zeros(len(cv), bool)]),
        taus=taus,
        still_owner=still[0],
        still_branch=still[1],
        still_s0=still[2],
    )


def _lane_forecast(lmap: LaneMap, lane_signal: np.ndarray, br_b: np.ndarray, s0_b: np.ndarray, lat_b: np.ndarray,
                   v: np.ndarray, accel: np.ndarray, length: np.ndarray, bike: np.ndarray,
                   taus: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lane-following hypotheses (NumPy path of ``prediction_jit.lane_forecast_kernel``):
    ``(pos (H, T, 2), dirn (H, T, 2), stops (H,))``."""
    a = np.clip(accel, -8.0, 2.0)
    a = np.where((a > 0) & (v > 12.0), 0.0, a)
    half = 0.5 * length
    tt = taus[None, :]
    t_stop = np.where(a < 0, v / np.maximum(-a, 1e-6), np.inf)[:, None]
    te = np.minimum(tt, t_stop)
    sigma = s0_b[:, None] + v[:, None] * te + 0.5 * a[:, None] * te * te
    stops = will_stop(lmap, br_b, s0_b, v, a, half, lane_signal)
    limit = np.where(stops, lmap.br_stop_s[br_b] - half - 0.5, np.inf)
    sigma = np.minimum(sigma, np.maximum(limit, s0_b)[:, None])
    p, dirn = lmap.branch_points(br_b[:, None], sigma)
    lat = np.where(
        bike[:, None],
        lat_b[:, None],
        np.sign(lat_b)[:, None] * np.maximum(np.abs(lat_b)[:, None] - LAT_DECAY * tt, 0.0),
    )
    p = p + lat[..., None] * np.stack([-dirn[..., 1], dirn[..., 0]], -1)
    return p, dirn, stops
