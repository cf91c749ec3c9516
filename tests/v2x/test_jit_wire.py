"""The wire kernels (``jit_wire``) give the bytes of the NumPy codec (``wire``)."""

import zlib

import numpy as np
import pytest
from v2xbench.envs.v2x_intersection.core.actors import ActorTable
from v2xbench.envs.v2x_intersection.core.jit import HAVE_JIT
from v2xbench.envs.v2x_intersection.sim.world import object_rows
from v2xbench.envs.v2x_intersection.v2x.wire import decode_message, encode_message, pack_rows

pytestmark = pytest.mark.skipif(not HAVE_JIT, reason="numba not installed")

if HAVE_JIT:
    import numba
    from v2xbench.envs.v2x_intersection.v2x.jit_wire import (
        _CRC_TABLE,
        builtin_message_kernel,
        decode_kernel,
        encode_kernel,
        float_bits,
        half_bits,
    )

    @numba.njit
    def _all_half_bits(bits):
        out = np.empty(bits.shape[0], np.int64)
        for i in range(bits.shape[0]):
            out[i] = half_bits(np.int64(bits[i]))
        return out


def _edge_bits() -> np.ndarray:
    """float32 bit patterns where float16 rounding is decided: every float16 value's float32, the
    ties between neighbours and one ulp either side of them, the subnormal and zero ranges, the
    overflow edge; with both signs, plus NaNs and infinities."""
    h = np.arange(2**15, dtype=np.uint32)
    exact = h.astype(np.uint16).view(np.float16).astype(np.float32).view(np.uint32)
    normal = (h << 13) + (112 << 23)
    ties = normal + 0x1000
    low = np.arange(0x32FF0000, 0x38810000, 7, dtype=np.uint32)  # zero, subnormals, first normals
    top = np.arange(0x477FC000, 0x47801000, dtype=np.uint32)  # 65504 .. 65536
    special = np.array([0x7F800000, 0x7F800001, 0x7FC00000, 0x7F802000, 0x7FBFFFFF], np.uint32)
    b = np.concatenate([exact, ties - 1, ties, ties + 1, low, top, special])
    b = b[b < 0x80000000]
    return np.concatenate([b, b | 0x80000000])


def test_half_bits_round_like_numpy():
    rng = np.random.default_rng(0)
    bits = np.concatenate([_edge_bits(), rng.integers(0, 2**32, 500_000, dtype=np.uint64).astype(np.uint32)])
    with np.errstate(all="ignore"):
        want = bits.view(np.float32).astype(np.float16).view(np.uint16).astype(np.int64)
    got = _all_half_bits(bits)
    bad = np.flatnonzero(got != want)
    assert len(bad) == 0, [(hex(bits[i]), hex(want[i]), hex(got[i])) for i in bad[:5]]


def test_crc_table_is_zlibs():
    data = np.random.default_rng(1).integers(0, 256, 300).astype(np.uint8)
    crc = 0xFFFFFFFF
    for byte in data:
        crc = int(_CRC_TABLE[(crc ^ int(byte)) & 0xFF]) ^ (crc >> 8)
    assert crc ^ 0xFFFFFFFF == zlib.crc32(data.tobytes())


@pytest.mark.parametrize("encoding,code", [("float16", 1), ("float32", 2)])
@pytest.mark.parametrize("pad", [0, 5])
def test_encode_kernel_matches_encode_message(encoding, code, pad):
    rng = np.random.default_rng(code * 10 + pad)
    for n in (1, 7, 40, 320):
        values = np.concatenate([rng.normal(0.0, 300.0, n // 2), rng.uniform(-1e4, 1e4, n - n // 2)]).astype(np.float32)
        values[: min(n, 3)] = np.array([0.0, -0.0, 6.1e-5], np.float32)[: min(n, 3)]
        for sender, tick in ((0, 0), (65535, 2**32 - 1), (7, 123456)):
            want = encode_message(sender, tick, values, encoding, header_bytes=16 + pad)
            got = encode_kernel(values, n, sender, tick, code, pad).tobytes()
            assert got == want, (n, sender, tick)
            assert decode_message(got, 16 + pad)[0:2] == (sender, tick)


def test_builtin_message_kernel_matches_pack_and_encode():
    """The world's one-kernel message: visible rows sorted by distance, cut to ``max_rows``, track
    ids wrapped for float16, encoded - the bytes of ``pack_rows`` + ``encode_message``."""
    rng = np.random.default_rng(2)
    n = 60
    t = ActorTable.empty(n)
    t.pos[:] = rng.uniform(-80, 80, (n, 2))
    t.yaw[:] = rng.uniform(-np.pi, np.pi, n)
    t.speed[:] = rng.uniform(0, 15, n)
    t.kind[:] = rng.integers(0, 5, n)
    t.length[:], t.width[:], t.height[:] = rng.uniform(0.5, 12, (3, n))
    t.actor_id[:] = rng.integers(0, 5000, n)  # ids past 2048 wrap in float16
    for encoding, code in (("float16", 1), ("float32", 2)):
        for max_rows, thr in ((32, 0.3), (4, 0.3), (32, 2.0)):
            vis = rng.uniform(0, 1, n)
            got = builtin_message_kernel(vis, thr, t.pos, t.yaw, t.speed, t.kind, t.length, t.width, t.height,
                                         t.actor_id, 3.0, -4.0, 0.7, max_rows, encoding == "float16", 9, 77, code, 0)
            rows = object_rows(t, np.flatnonzero(vis >= thr), np.array([3.0, -4.0]), 0.7)
            length, payload = pack_rows(rows, max_rows * 10, encoding)
            want = encode_message(9, 77, payload[:length], encoding) if length else b""
            assert got.tobytes() == want, (encoding, max_rows, thr)


def test_float_bits_are_numpys_for_every_float16():
    h = np.arange(2**16, dtype=np.uint16)
    want = h.view(np.float16).astype(np.float32).view(np.uint32).astype(np.int64)
    got = np.array([float_bits(int(x)) for x in h], np.int64)
    assert (got == want).all()


@pytest.mark.parametrize("encoding", ["float16", "float32"])
@pytest.mark.parametrize("header_bytes", [16, 20])
def test_decode_kernel_matches_decode_message(encoding, header_bytes):
    """Valid messages decode to the codec's values; every corruption the codec rejects (truncation,
    trailing bytes, magic, version, encoding code, padding, payload or header bits) the kernel
    rejects too."""
    rng = np.random.default_rng(len(encoding) + header_bytes)
    for n in (0, 1, 10, 320):
        values = rng.uniform(-1e4, 1e4, n).astype(np.float32)
        data = encode_message(3, 99, values, encoding, header_bytes)
        ok, sender, tick, payload = decode_kernel(np.frombuffer(data, np.uint8), header_bytes)
        want = decode_message(data, header_bytes)
        assert ok and (sender, tick) == want[:2] and payload.tobytes() == want[2].tobytes()
        bad = [data[:-1], data + b"\x00", data[:5]]
        for pos in (0, 2, 3, 6, 8, 12, header_bytes - 1, len(data) - 1):
            b = bytearray(data)
            b[pos] ^= 0x10
            bad.append(bytes(b))
        for b in bad:
            with pytest.raises(ValueError):
                decode_message(b, header_bytes)
            assert not decode_kernel(np.frombuffer(b, np.uint8), header_bytes)[0]
