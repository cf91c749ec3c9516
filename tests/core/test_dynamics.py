"""Tests of the ego's kinematic bicycle model (and its inverse) and of IDM, by hand."""

from __future__ import annotations

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.core.dynamics import (
    IDMParams,
    VehicleParams,
    bicycle_inverse,
    bicycle_step,
    idm_accel,
)

P = VehicleParams()
DT = 0.1


def run(n, throttle=0.0, steer=0.0, brake=0.0, x=0.0, y=0.0, yaw=0.0, v=0.0, params=P):
    xs, ys, yaws, vs = [x], [y], [yaw], [v]
    for _ in range(n):
        x, y, yaw, v, _ = bicycle_step(x, y, yaw, v, throttle, steer, brake, params, DT)
        xs.append(x), ys.append(y), yaws.append(yaw), vs.append(v)
    return np.array(xs), np.array(ys), np.array(yaws), np.array(vs)


# ------------------------------------------------------------------------------ bicycle model


def test_full_throttle_from_rest_for_one_second():
    # v_{k+1} = v_k (1 - drag dt) + max_accel dt  =>  v_10 = max_accel / drag * (1 - (1 - drag dt)^10)
    x, y, yaw, v = run(10, throttle=1.0)
    q = 1.0 - P.drag * DT
    expected = P.max_accel / P.drag * (1.0 - q**10)
    assert expected == pytest.approx(3.4685, abs=1e-3)  # ~ 3.5 m/s minus a little drag
    assert v[-1] == pytest.approx(expected, rel=1e-12)
    # semi-implicit Euler: the position uses the new speed, x_10 = dt * sum(v_1..v_10)
    assert x[-1] == pytest.approx(DT * v[1:].sum(), rel=1e-12)
    assert np.all(y == 0.0) and np.all(yaw == 0.0)


def test_first_step_values():
    x, y, yaw, v, a = bicycle_step(0.0, 0.0, 0.0, 10.0, 0.5, 0.0, 0.0, P, DT)
    # a = 0.5 * 3.5 - 0.02 * 10 = 1.55 ; v = 10.155 ; x = 1.0155
    assert a == pytest.approx(1.55)
    assert v == pytest.approx(10.155)
    assert x == pytest.approx(1.0155)


def test_speed_is_capped():
    _, _, _, v = run(200, throttle=1.0, v=24.0)
    assert v.max() <= P.max_speed + 1e-12
    assert v[-1] == pytest.approx(P.max_speed)


def test_braking_to_zero_never_reverses():
    x, y, yaw, v = run(40, brake=1.0, v=12.0)
    assert np.all(v >= 0.0)
    assert np.all(np.diff(v) <= 0.0)
    assert np.all(np.diff(x) >= 0.0)  # never moves backwards
    assert v[-1] == 0.0
    # 12 m/s at ~8 m/s^2 stops within ~1.6 s: the first 15 ticks all brake at ~full force
    stop = int(np.argmax(v == 0.0))
    assert 14 <= stop <= 16
    assert x[-1] == x[stop]  # stays put once stopped
    # brake at rest does nothing either
    x2, _, _, v2, a2 = bicycle_step(5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, P, DT)
    assert (x2, v2, a2) == (5.0, 0.0, 0.0)


def test_reported_accel_is_the_realized_one():
    _, _, _, v1, a = bicycle_step(0.0, 0.0, 0.0, 0.3, 0.0, 0.0, 1.0, P, DT)
    assert v1 == 0.0
    assert a == pytest.approx(-3.0)  # (0 - 0.3) / 0.1, not -8


@pytest.mark.parametrize("steer", [0.5, -0.3, 1.0])
def test_constant_steer_traces_a_circle(steer):
    v0 = 5.0
    throttle = P.drag * v0 / P.max_accel  # holds the speed exactly
    x, y, yaw, v = run(400, throttle=throttle, steer=steer, v=v0)
    np.testing.assert_allclose(v, v0, rtol=1e-12)
    delta = steer * P.max_steer
    radius = P.wheelbase / np.tan(abs(delta))
    # yaw rate v tan(delta) / L
    rate = np.diff(np.unwrap(yaw)) / DT
    np.testing.assert_allclose(rate, v0 * np.tan(delta) / P.wheelbase, rtol=1e-9)
    # least-squares circle through the trace: x^2 + y^2 = 2 a x + 2 b y + c
    a_mat = np.stack([2 * x, 2 * y, np.ones_like(x)], -1)
    (cx, cy, c), *_ = np.linalg.lstsq(a_mat, x**2 + y**2, rcond=None)
    r_fit = np.sqrt(c + cx**2 + cy**2)
    assert r_fit == pytest.approx(radius, rel=2e-3)
    np.testing.assert_allclose(np.hypot(x - cx, y - cy), r_fit, rtol=1e-6)
    # left steer turns counter-clockwise: the centre is on the left of the start heading (+y)
    assert np.sign(cy) == np.sign(steer)


def test_yaw_is_wrapped():
    _, _, yaw, _ = run(600, throttle=0.03, steer=1.0, v=5.0)
    assert np.all(yaw >= -np.pi) and np.all(yaw < np.pi)


def test_vectorized_matches_scalar():
    rng = np.random.default_rng(0)
    n = 50
    state = [
        rng.uniform(-10, 10, n),
        rng.uniform(-10, 10, n),
        rng.uniform(-3, 3, n),
        rng.uniform(0, 20, n),
    ]
    ctrl = [rng.uniform(0, 1, n), rng.uniform(-1, 1, n), rng.uniform(0, 1, n)]
    out = bicycle_step(*state, *ctrl, P, DT)
    for k in (0, 17, 49):
        one = bicycle_step(*(s[k] for s in state), *(c[k] for c in ctrl), P, DT)
        np.testing.assert_allclose([o[k] for o in out], one, rtol=1e-12)


def test_inverse_recovers_controls_inside_limits():
    rng = np.random.default_rng(1)
    n = 300
    yaw, v = rng.uniform(-3, 3, n), rng.uniform(1.0, 20.0, n)
    use_brake = rng.random(n) < 0.4
    throttle = np.where(use_brake, 0.0, rng.uniform(0.0, 1.0, n))
    brake = np.where(use_brake, rng.uniform(0.0, 0.1, n), 0.0)  # small: keeps v > 0
    steer = rng.uniform(-1.0, 1.0, n)
    _, _, yaw1, v1, _ = bicycle_step(0.0, 0.0, yaw, v, throttle, steer, brake, P, DT)
    assert np.all((v1 > 0) & (v1 < P.max_speed))
    th, st, br = bicycle_inverse(yaw, v, yaw1, v1, P, DT)
    np.testing.assert_allclose(th, throttle, atol=1e-9)
    np.testing.assert_allclose(br, brake, atol=1e-9)
    np.testing.assert_allclose(st, steer, atol=1e-9)


def test_forward_of_inverse_reproduces_a_logged_trajectory():
    rng = np.random.default_rng(2)
    x, y, yaw, v = 0.0, 0.0, 0.3, 8.0
    log = [(x, y, yaw, v)]
    for _ in range(200):  # a random drive that never stops
        th = rng.uniform(0, 0.6) if v < 15 else 0.0
        br = rng.uniform(0, 0.05) if v > 3 else 0.0
        x, y, yaw, v, _ = bicycle_step(x, y, yaw, v, th, rng.uniform(-0.8, 0.8), br, P, DT)
        log.append((x, y, yaw, v))
    log = np.array(log)
    th, st, br = bicycle_inverse(log[:-1, 2], log[:-1, 3], log[1:, 2], log[1:, 3], P, DT)
    x, y, yaw, v = log[0]
    for k in range(200):
        x, y, yaw, v, _ = bicycle_step(x, y, yaw, v, th[k], st[k], br[k], P, DT)
        np.testing.assert_allclose([x, y, yaw, v], log[k + 1], atol=1e-6)


def test_inverse_clips_to_actuator_limits():
    # a yaw change too large for the steering and a deceleration beyond the brakes
    th, st, br = bicycle_inverse(0.0, 10.0, 1.0, 5.0, P, DT)
    assert st == 1.0 and br == 1.0 and th == 0.0
    th, st, br = bicycle_inverse(0.0, 0.0, 0.0, 5.0, P, DT)
    assert th == 1.0 and br == 0.0 and st == 0.0  # v_next > 0, no yaw change


# ------------------------------------------------------------------------------ IDM

IDM = IDMParams()


def test_idm_free_road_from_rest_accelerates_at_accel():
    assert float(idm_accel(0.0, 10.0, np.inf, 0.0, IDM)) == pytest.approx(IDM.accel)


def test_idm_equilibrium_at_desired_speed():
    assert float(idm_accel(10.0, 10.0, np.inf, 0.0, IDM)) == pytest.approx(0.0, abs=1e-12)
    # half the desired speed: a (1 - 0.5^4) = 2 * 15/16
    assert float(idm_accel(5.0, 10.0, np.inf, 0.0, IDM)) == pytest.approx(2.0 * 15.0 / 16.0)
    # faster than desired: decelerates
    assert float(idm_accel(12.0, 10.0, np.inf, 0.0, IDM)) < 0.0


def test_idm_stopped_leader_at_min_gap_brakes_hard():
    a = float(idm_accel(10.0, 13.9, IDM.min_gap, 10.0, IDM))
    assert a == pytest.approx(-IDM.max_brake)
    # at rest, exactly at the jam distance: no push forward
    assert float(idm_accel(0.0, 13.9, IDM.min_gap, 0.0, IDM)) == pytest.approx(0.0, abs=1e-12)


def test_idm_hand_computed_interaction_term():
    v, v0, gap, dv = 10.0, 20.0, 40.0, 2.0
    s_star = IDM.min_gap + v * IDM.time_headway + v * dv / (2 * np.sqrt(IDM.accel * IDM.decel))
    expected = IDM.accel * (1 - (v / v0) ** 4 - (s_star / gap) ** 2)
    assert float(idm_accel(v, v0, gap, dv, IDM)) == pytest.approx(expected, rel=1e-12)


def test_idm_follows_a_leader_without_collision():
    # follower behind a leader that brakes to a stop: the follower stops behind it
    dt, xl, vl, xf, vf = 0.1, 60.0, 10.0, 0.0, 10.0
    for _ in range(400):
        vl = max(vl - 3.0 * dt, 0.0)
        xl += vl * dt
        a = float(idm_accel(vf, 13.9, xl - xf - 4.5, vf - vl, IDM))
        vf = max(vf + a * dt, 0.0)
        xf += vf * dt
        assert xl - xf - 4.5 > 0.5
    assert vf < 0.05
    assert xl - xf - 4.5 == pytest.approx(IDM.min_gap, abs=0.5)


def test_idm_vectorized():
    v = np.array([0.0, 10.0, 10.0])
    out = idm_accel(
        v,
        np.array([10.0, 10.0, 13.9]),
        np.array([np.inf, np.inf, IDM.min_gap]),
        np.array([0.0, 0.0, 10.0]),
        IDM,
    )
    np.testing.assert_allclose(out, [IDM.accel, 0.0, -IDM.max_brake], atol=1e-12)
