"""Tests of the RSU -> ego V2X channel: codec, byte counting, BPS, latency, loss, cap, actions."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.v2x.channel import (
    HEADER_SIZE,
    NUM_OBJECT_FIELDS,
    OBJECT_FIELDS,
    PAYLOAD_LIMIT,
    Channel,
    ChannelConfig,
    decode_message,
    empty_message,
    encode_message,
    max_objects,
    message_space,
    pack_objects,
    unpack_objects,
    validate_message,
)


def make(seed: int = 0, **kw) -> Channel:
    return Channel(ChannelConfig(**kw), np.random.default_rng(seed))


def ramp(n: int, m: int = 512) -> np.ndarray:
    p = np.zeros(m, np.float32)
    p[:n] = np.arange(n, dtype=np.float32) * 0.5 - 10.0
    return p


# ------------------------------------------------------------------------------------ config


def test_config_defaults():
    c = ChannelConfig()
    assert (c.latency_ticks, c.loss_prob, c.bandwidth_bytes_per_s) == (1, 0.0, None)
    assert (c.header_bytes, c.encoding, c.dt) == (16, "float16", 0.1)
    assert HEADER_SIZE == 16
    assert c.window_ticks == 10
    assert c.message_bytes(0) == 0 and c.message_bytes(10) == 16 + 20


@pytest.mark.parametrize(
    "field,value",
    [
        ("latency_ticks", -1),
        ("latency_ticks", 1.5),
        ("latency_ticks", True),
        ("loss_prob", -0.1),
        ("loss_prob", 1.5),
        ("loss_prob", float("nan")),
        ("bandwidth_bytes_per_s", 0.0),
        ("bandwidth_bytes_per_s", -5.0),
        ("bandwidth_bytes_per_s", float("inf")),
        ("header_bytes", 8),
        ("header_bytes", 16.0),
        ("max_payload_floats", 0),
        ("max_payload_floats", 70000),
        ("encoding", "float64"),
        ("dt", 0.0),
        ("dt", -0.1),
        ("dt", float("nan")),
    ],
)
def test_config_validation_names_field_and_value(field, value):
    with pytest.raises(ValueError) as e:
        ChannelConfig(**{field: value})
    msg = str(e.value)
    assert f"ChannelConfig.{field}" in msg
    assert repr(value) in msg


def test_config_is_frozen():
    c = ChannelConfig()
    with pytest.raises(AttributeError):
        c.loss_prob = 0.5  # type: ignore[misc]


# ------------------------------------------------------------------------------------- codec


@pytest.mark.parametrize("encoding,itemsize", [("float16", 2), ("float32", 4)])
@pytest.mark.parametrize("n", [1, 7, 512])
def test_encode_decode_round_trip(encoding, itemsize, n):
    rng = np.random.default_rng(n)
    x = rng.uniform(-150, 150, n).astype(np.float32)
    data = encode_message(42, 1234, x, encoding)
    assert isinstance(data, bytes)
    assert len(data) == HEADER_SIZE + n * itemsize
    sid, tick, y = decode_message(data)
    assert (sid, tick) == (42, 1234)
    assert y.dtype == np.float32 and y.shape == (n,)
    if encoding == "float32":
        np.testing.assert_array_equal(y, x)
    else:
        np.testing.assert_array_equal(y, x.astype(np.float16).astype(np.float32))
        # float16 below 256 m: step <= 0.125 m, rounding error <= 0.0625 m
        assert np.abs(y - x).max() <= 0.0625


def test_header_layout():
    data = encode_message(7, 99, np.array([1.0, 2.0], np.float32), "float32")
    magic, version, code, sender, length, tick, _crc = struct.unpack_from("<2sBBHHII", data)
    assert (magic, version, code, sender, length, tick) == (b"VX", 1, 2, 7, 2, 99)
    assert np.frombuffer(data[16:], "<f4").tolist() == [1.0, 2.0]


def test_header_padding_round_trip():
    x = np.arange(5, dtype=np.float32)
    data = encode_message(1, 2, x, "float16", header_bytes=24)
    assert len(data) == 24 + 10
    assert data[16:24] == b"\x00" * 8
    np.testing.assert_array_equal(decode_message(data, header_bytes=24)[2], x)
    bad = bytearray(data)
    bad[20] = 1
    with pytest.raises(ValueError, match="padding"):
        decode_message(bytes(bad), header_bytes=24)


def test_empty_payload_codec():
    data = encode_message(0, 0, np.zeros(0, np.float32))
    assert len(data) == HEADER_SIZE
    assert decode_message(data)[2].shape == (0,)


def test_decode_rejects_corrupt_and_truncated():
    data = encode_message(3, 10, np.linspace(-5, 5, 20).astype(np.float32))
    with pytest.raises(ValueError, match="truncated"):
        decode_message(data[:10])
    with pytest.raises(ValueError, match="truncated"):
        decode_message(data[:-2])
    with pytest.raises(ValueError, match="trailing"):
        decode_message(data + b"\x00\x00")
    with pytest.raises(ValueError, match="magic"):
        decode_message(b"XX" + data[2:])
    with pytest.raises(ValueError, match="version"):
        decode_message(data[:2] + b"\x09" + data[3:])
    with pytest.raises(ValueError, match="encoding"):
        decode_message(data[:3] + b"\x07" + data[4:])
    for pos in (5, 9, 13, HEADER_SIZE + 3, len(data) - 1):  # header fields, crc, payload
        bad = bytearray(data)
        bad[pos] ^= 0x10
        with pytest.raises(ValueError, match="checksum|corrupt"):
            decode_message(bytes(bad))


def test_encode_rejects_bad_input():
    with pytest.raises(ValueError, match="NaN or inf"):
        encode_message(0, 0, np.array([1.0, np.nan]))
    with pytest.raises(ValueError, match="overflow float16"):
        encode_message(0, 0, np.array([1e6]), "float16")
    encode_message(0, 0, np.array([1e6]), "float32")  # fine in float32
    with pytest.raises(ValueError, match="1-D"):
        encode_message(0, 0, np.zeros((2, 2)))
    with pytest.raises(ValueError, match="sender_id"):
        encode_message(70000, 0, np.zeros(2))
    with pytest.raises(ValueError, match="tick"):
        encode_message(0, -1, np.zeros(2))
    with pytest.raises(ValueError, match="encoding"):
        encode_message(0, 0, np.zeros(2), "int8")


# ------------------------------------------------------------------------ bytes and bandwidth


@pytest.mark.parametrize("encoding,itemsize", [("float16", 2), ("float32", 4)])
@pytest.mark.parametrize("header", [16, 40])
def test_bytes_on_air_is_header_plus_payload(encoding, itemsize, header):
    ch = make(encoding=encoding, header_bytes=header)
    total = 0
    for t, n in enumerate([1, 10, 0, 512, 3]):
        b = ch.send(t, 1, n, ramp(n))
        expected = 0 if n == 0 else header + n * itemsize
        assert b == expected
        assert ch.stats()["last_message_bytes"] == expected
        total += expected
    s = ch.stats()
    assert s["bytes_sent_total"] == total
    assert s["messages_sent"] == 4  # the length-0 send sends nothing


def test_length_zero_sends_nothing():
    ch = make(latency_ticks=0)
    assert ch.send(0, 1, 0, np.full(512, np.nan, np.float32)) == 0  # unused part not checked
    assert ch.receive(0) == []
    s = ch.stats()
    assert s["bytes_sent_total"] == 0 and s["messages_sent"] == 0 and s["bps"] == 0.0


def test_bps_exact_over_known_sequence():
    # float16, 16 B header: lengths 100, 0, 50 at ticks 0, 1, 2 then silence to tick 9.
    ch = make(latency_ticks=0)
    ch.send(0, 1, 100, ramp(100))  # 216 B
    ch.send(1, 1, 0, ramp(0))
    ch.send(2, 1, 50, ramp(50))  # 116 B
    s = ch.stats()
    assert s["bytes_sent_total"] == 332
    assert s["ticks_elapsed"] == 3
    assert s["bps"] == pytest.approx(332 / 0.3, rel=1e-12)
    for t in range(3, 10):
        ch.receive(t)
    s = ch.stats()
    assert s["seconds_elapsed"] == pytest.approx(1.0)
    assert s["bps"] == pytest.approx(332.0, rel=1e-12)
    assert s["peak_bps"] == pytest.approx(332.0, rel=1e-12)


def test_peak_bps_sliding_window():
    ch = make(latency_ticks=0)
    # 116 B at every tick 0..29 (3 s): any 10-tick window holds 1160 B.
    for t in range(30):
        ch.send(t, 0, 50, ramp(50))
    s = ch.stats()
    assert s["peak_bps"] == pytest.approx(1160.0)
    assert s["bps"] == pytest.approx(116 * 30 / 3.0)
    # a burst: 3 messages in ticks 40..42, then a gap, then 1 at tick 60
    for t in (40, 41, 42):
        ch.send(t, 0, 500, ramp(500))  # 1016 B each
    ch.send(60, 0, 500, ramp(500))
    assert ch.stats()["peak_bps"] == pytest.approx(3048.0)
    ch.reset()
    s = ch.stats()
    assert s["peak_bps"] == 0.0 and s["bytes_sent_total"] == 0 and s["ticks_elapsed"] == 0


def test_bandwidth_cap_drops_what_exceeds():
    # cap 1000 B/s over a 10-tick window; 216 B messages: 4 fit (864), the 5th would be 1080.
    ch = make(latency_ticks=0, bandwidth_bytes_per_s=1000.0)
    sent = [ch.send(t, 1, 100, ramp(100)) for t in range(10)]
    assert sent == [216] * 4 + [0] * 6
    s = ch.stats()
    assert s["messages_sent"] == 4 and s["messages_dropped_bandwidth"] == 6
    assert s["bytes_sent_total"] == 864 and s["bytes_dropped_bandwidth"] == 6 * 216
    assert s["peak_bps"] <= 1000.0
    # a smaller message still fits in the remaining 136 B
    assert ch.send(9, 1, 50, ramp(50)) == 116
    # once tick 0 leaves the window (tick 10), 216 B are freed again
    assert ch.send(10, 1, 100, ramp(100)) == 216
    assert ch.send(10, 1, 100, ramp(100)) == 0
    # dropped messages are never delivered
    got = ch.receive(10)
    assert len(got) == 6  # 4 + 1 + 1 delivered with latency 0


def test_bandwidth_cap_never_exceeded_random():
    rng = np.random.default_rng(5)
    cap = 3000.0
    ch = make(latency_ticks=0, bandwidth_bytes_per_s=cap)
    per_tick = []
    for t in range(300):
        b = 0
        for _ in range(rng.integers(0, 3)):
            b += ch.send(t, 0, int(rng.integers(0, 512)), ramp(511))
        per_tick.append(b)
    windows = np.convolve(per_tick, np.ones(10), "full")
    assert windows.max() <= cap
    assert ch.stats()["peak_bps"] == pytest.approx(windows.max())
    assert ch.stats()["messages_dropped_bandwidth"] > 0


def test_message_larger_than_cap_always_dropped():
    ch = make(bandwidth_bytes_per_s=100.0)
    assert ch.send(0, 1, 100, ramp(100)) == 0
    assert ch.stats()["messages_dropped_bandwidth"] == 1


# ----------------------------------------------------------------------------------- latency


@pytest.mark.parametrize("k", [0, 1, 3, 7])
def test_latency_delivers_exactly_k_ticks_later(k):
    ch = make(latency_ticks=k)
    x = ramp(20)
    delivered_at = {}
    for t in range(20):
        if t in (2, 5):
            ch.send(t, 9, 20, x + t)
        for sid, sent, p in ch.receive(t):
            assert sid == 9
            delivered_at[sent] = t
            np.testing.assert_allclose(p, (x + sent)[:20], atol=0.02)
    assert delivered_at == {2: 2 + k, 5: 5 + k}
    assert ch.stats()["messages_delivered"] == 2
    assert ch.stats()["bytes_delivered_total"] == 2 * (16 + 40)


def test_receive_order_and_latest():
    ch = make(latency_ticks=2)
    ch.send(0, 1, 3, ramp(3))
    ch.send(0, 2, 3, ramp(3))
    ch.send(1, 3, 3, ramp(3))
    assert ch.receive(1) == []
    # skipped tick 2: receive(3) returns everything due so far, oldest first
    got = ch.receive(3)
    assert [(s, t) for s, t, _ in got] == [(1, 0), (2, 0), (3, 1)]
    assert ch.receive(3) == []  # delivered exactly once
    ch.send(4, 5, 3, ramp(3))
    ch.send(4, 6, 3, ramp(3))
    assert ch.receive_latest(5) is None
    sid, sent, _ = ch.receive_latest(6)
    assert (sid, sent) == (6, 4)
    assert ch.last_delivered[0] == 6
    assert ch.stats()["messages_delivered"] == 5
    assert ch.pending == 0


def test_ticks_cannot_go_backwards():
    ch = make()
    ch.send(5, 1, 3, ramp(3))
    with pytest.raises(ValueError, match="backwards"):
        ch.send(4, 1, 3, ramp(3))
    with pytest.raises(ValueError, match="backwards"):
        ch.receive(3)


# -------------------------------------------------------------------------------------- loss


def _losses(seed: int, p: float, n: int = 2000) -> np.ndarray:
    ch = make(seed=seed, latency_ticks=0, loss_prob=p)
    lost = []
    for t in range(n):
        ch.send(t, 1, 4, ramp(4))
        lost.append(len(ch.receive(t)) == 0)
    s = ch.stats()
    assert s["messages_lost"] == sum(lost)
    # lost messages were transmitted: their bytes count as sent, not as delivered
    assert s["bytes_sent_total"] == n * 24
    assert s["bytes_delivered_total"] == (n - sum(lost)) * 24
    return np.array(lost)


def test_loss_prob_one_loses_all_zero_none():
    assert _losses(0, 1.0).all()
    assert not _losses(0, 0.0).any()


def test_loss_rate_and_determinism():
    a = _losses(123, 0.3)
    assert 0.27 < a.mean() < 0.33  # 2000 draws: std ~0.01
    np.testing.assert_array_equal(a, _losses(123, 0.3))
    assert not np.array_equal(a, _losses(124, 0.3))


def test_loss_uses_given_rng_only():
    rng = np.random.default_rng(7)
    ch = Channel(ChannelConfig(loss_prob=0.5, latency_ticks=0), rng)
    state = np.random.get_state()[1].copy()
    for t in range(10):
        ch.send(t, 0, 2, ramp(2))
    np.testing.assert_array_equal(np.random.get_state()[1], state)
    ref = np.random.default_rng(7).random(10) < 0.5
    assert ch.stats()["messages_lost"] == int(ref.sum())


# -------------------------------------------------------------------------------- the action


def test_message_space_and_empty_message():
    cfg = ChannelConfig(max_payload_floats=64)
    sp = message_space(cfg)
    assert sp["length"].n == 65
    assert sp["payload"].shape == (64,) and sp["payload"].dtype == np.float32
    assert sp["payload"].high.max() == PAYLOAD_LIMIT and sp["payload"].low.min() == -PAYLOAD_LIMIT
    sp.seed(0)
    for _ in range(5):
        a = sp.sample()
        n, p = validate_message(a, cfg)
        assert n == int(a["length"])
        assert make(max_payload_floats=64, latency_ticks=0).send(0, 0, n, p) == cfg.message_bytes(n)
    e = empty_message(cfg)
    assert sp.contains(e)
    assert validate_message(e, cfg)[0] == 0


def test_validate_message_errors():
    cfg = ChannelConfig(max_payload_floats=32)
    ok = np.zeros(32, np.float32)
    with pytest.raises(ValueError, match=r"oversized message.*max_payload_floats=32"):
        validate_message({"length": 33, "payload": ok}, cfg)
    with pytest.raises(ValueError, match=">= 0"):
        validate_message({"length": -1, "payload": ok}, cfg)
    with pytest.raises(ValueError, match="integer"):
        validate_message({"length": 2.5, "payload": ok}, cfg)
    with pytest.raises(ValueError, match=r"wrong shape \(31,\).*\(32,\)"):
        validate_message({"length": 3, "payload": np.zeros(31, np.float32)}, cfg)
    with pytest.raises(ValueError, match="wrong shape"):
        validate_message({"length": 3, "payload": np.zeros((2, 16), np.float32)}, cfg)
    with pytest.raises(ValueError, match="wrong dtype"):
        validate_message({"length": 3, "payload": np.zeros(32, np.int32)}, cfg)
    with pytest.raises(ValueError, match="missing"):
        validate_message({"length": 3}, cfg)
    bad = ok.copy()
    bad[2] = np.nan
    with pytest.raises(ValueError, match=r"NaN/inf.*index 2"):
        validate_message({"length": 3, "payload": bad}, cfg)
    bad[2] = np.inf
    with pytest.raises(ValueError, match="NaN/inf"):
        validate_message({"length": 3, "payload": bad}, cfg)
    # NaN beyond the used part is ignored
    assert validate_message({"length": 2, "payload": bad}, cfg)[0] == 2
    big = ok.copy()
    big[0] = 2e4
    with pytest.raises(ValueError, match="out of range"):
        validate_message({"length": 1, "payload": big}, cfg)
    # numpy integer lengths (as Discrete.sample gives) are fine; float64 payloads are cast
    n, p = validate_message({"length": np.int64(4), "payload": np.zeros(32)}, cfg)
    assert n == 4 and p.dtype == np.float32


def test_send_rejects_bad_messages():
    ch = make(max_payload_floats=16)
    with pytest.raises(ValueError, match=r"oversized message.*16"):
        ch.send(0, 1, 17, np.zeros(17, np.float32))
    with pytest.raises(ValueError, match="NaN/inf"):
        ch.send(0, 1, 2, np.array([0.0, np.nan], np.float32))
    with pytest.raises(ValueError, match="cannot hold"):
        ch.send(0, 1, 5, np.zeros(3, np.float32))
    with pytest.raises(ValueError, match="sender_id"):
        ch.send(0, -1, 2, np.zeros(2, np.float32))
    with pytest.raises(ValueError, match="oversized"):
        ch.send_action(0, 1, {"length": 99, "payload": np.zeros(16, np.float32)})
    assert ch.stats()["bytes_sent_total"] == 0


# ------------------------------------------------------------------------------- pack/unpack


def _objects(k: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    o = np.zeros((k, NUM_OBJECT_FIELDS), np.float32)
    o[:, 0] = rng.integers(0, 8, k)
    o[:, 1:3] = rng.uniform(-199, 199, (k, 2))
    o[:, 3] = rng.uniform(-np.pi, np.pi, k)
    o[:, 4:7] = rng.uniform(0.5, 12, (k, 3))
    o[:, 7:9] = rng.uniform(-20, 20, (k, 2))
    o[:, 9] = rng.integers(0, 2000, k)
    return o


def test_object_fields():
    assert OBJECT_FIELDS[0] == "class_id" and OBJECT_FIELDS[-1] == "track_id"
    assert NUM_OBJECT_FIELDS == 10
    assert max_objects(512) == 51


@pytest.mark.parametrize("encoding", ["float16", "float32"])
def test_pack_unpack_round_trip_through_channel(encoding):
    objs = _objects(12)
    length, payload = pack_objects(objs, 512, encoding)
    assert length == 120 and payload.shape == (512,) and payload.dtype == np.float32
    assert not payload[length:].any()
    np.testing.assert_array_equal(unpack_objects(payload, length), objs)
    ch = make(latency_ticks=0, encoding=encoding)
    ch.send_action(0, 3, {"length": length, "payload": payload})
    ((_, _, received),) = ch.receive(0)
    back = unpack_objects(received, len(received))
    assert back.shape == objs.shape
    if encoding == "float32":
        np.testing.assert_array_equal(back, objs)
    else:
        # class ids and track ids (< 2048) exact; positions within 0.0625 m below 256 m
        np.testing.assert_array_equal(back[:, [0, 9]], objs[:, [0, 9]])
        assert np.abs(back[:, 1:3] - objs[:, 1:3]).max() <= 0.0625
        np.testing.assert_allclose(back, objs, rtol=2**-11, atol=1e-3)


def test_pack_truncates_to_fit():
    objs = _objects(100)
    length, payload = pack_objects(objs, 64)
    assert length == 60 and length // NUM_OBJECT_FIELDS == 6
    np.testing.assert_array_equal(unpack_objects(payload, length), objs[:6])
    assert pack_objects(np.zeros((0, NUM_OBJECT_FIELDS)), 64)[0] == 0


def test_pack_track_id_wraps_in_float16():
    objs = _objects(2)
    objs[:, 9] = [2047, 5000]
    _, p16 = pack_objects(objs, 64, "float16")
    assert unpack_objects(p16, 20)[:, 9].tolist() == [2047, 5000 % 2048]
    _, p32 = pack_objects(objs, 64, "float32")
    assert unpack_objects(p32, 20)[:, 9].tolist() == [2047, 5000]


def test_pack_unpack_errors():
    with pytest.raises(ValueError, match="shape"):
        pack_objects(np.zeros((3, 9)))
    bad = _objects(2)
    bad[1, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        pack_objects(bad)
    with pytest.raises(ValueError, match="multiple"):
        unpack_objects(np.zeros(32), 15)
    with pytest.raises(ValueError, match="cannot hold"):
        unpack_objects(np.zeros(8), 10)


# ------------------------------------------------------------------------------------- speed


def test_step_builtin_matches_step_with_default_message():
    """World.step_builtin (the envs' path, message not checked twice) sends exactly what
    step(control, default_rsu_message()) sends, with the same results."""
    from v2xbench.envs.v2x_intersection.sim.config import make_config
    from v2xbench.envs.v2x_intersection.sim.world import World

    for policy in ("share_objects", "none"):
        _compare_builtin(World, make_config(town="Town03", latency_ticks=1, rsu_policy=policy), policy)


def _compare_builtin(World, cfg, policy):
    worlds = [World(cfg) for _ in range(2)]
    for w in worlds:
        w.reset(seed=5)
    sent = 0
    for k in range(120):
        a = np.array([0.5, 0.05 * np.sin(k / 9), 0.0])
        ev0 = worlds[0].step(a, worlds[0].default_rsu_message())
        ev1 = worlds[1].step_builtin(a)
        assert ev0 == ev1
        s0, s1 = worlds[0].channel.stats(), worlds[1].channel.stats()
        assert s0 == s1
        i0, i1 = worlds[0].inbox, worlds[1].inbox
        assert (i0 is None) == (i1 is None)
        if i0 is not None:
            assert i0[:2] == i1[:2] and i0[2].tobytes() == i1[2].tobytes()
        sent = s1["messages_sent"]
    assert (sent > 0) == (policy != "none")
