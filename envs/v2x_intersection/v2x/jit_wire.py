"""numba kernels for the V2X wire format (:mod:`.wire`): one call turns the built-in RSU policy's
object rows into the message bytes that :func:`.wire.encode_message` would give.

:func:`encode_kernel` writes the header, the payload (float32 -> float16 with round-to-nearest-even,
as NumPy's ``astype``, or float32 as is) and the CRC-32 (zlib's polynomial) into one ``uint8``
array. :func:`builtin_message_kernel` adds what ``World.send_builtin`` does before encoding: the
slot-0 unit's visible actors as object rows sorted by distance, cut to what fits a message, with
track ids wrapped for float16. :func:`decode_kernel` reads a message back with every check of
:func:`.wire.decode_message`; where one fails, the channel lets the codec raise its error.
``tests/v2x/test_jit_wire.py`` compares both ways with the NumPy codec (float16 edge cases, every
float16 value, corrupted messages).
"""

from __future__ import annotations

import numpy as np

from ..core.jit import _njit, _njit_inline
from ..perception.jit_perception import seen_rows_kernel
from .wire import (
    _TRACK_ID_COL,
    ENCODING_CODES,
    FLOAT16_TRACK_ID_MODULUS,
    FORMAT_SHIFT,
    HEADER_SIZE,
    MAGIC,
    NUM_OBJECT_FIELDS,
    PAYLOAD_FORMATS,
    WIRE_VERSION,
)


def _crc_table() -> np.ndarray:
    """The 256-entry table of the reflected CRC-32 polynomial 0xEDB88320 (zlib's CRC-32; the tests
    compare a CRC computed with it to ``zlib.crc32``)."""
    table = np.empty(256, np.int64)
    for n in range(256):
        c = n
        for _ in range(8):
            c = (c >> 1) ^ 0xEDB88320 if c & 1 else c >> 1
        table[n] = c
    return table


_CRC_TABLE = _crc_table()
_MAGIC0, _MAGIC1 = MAGIC[0], MAGIC[1]
_TRACK_MOD = np.float32(FLOAT16_TRACK_ID_MODULUS)
_F16, _F32 = ENCODING_CODES["float16"], ENCODING_CODES["float32"]  # the wire codes of the encodings
_CODE_MASK = (1 << FORMAT_SHIFT) - 1  # header byte 3: the encoding's bits (the format's above)
_MAX_FORMAT = max(PAYLOAD_FORMATS.values())


@_njit_inline
def half_bits(b):  # pragma: no cover
    """float16 bits of the float32 with bits ``b`` (an int64 holding the uint32), rounded to nearest
    even as NumPy's ``astype(np.float16)``: overflow to inf, subnormals, NaN payloads as NumPy keeps them."""
    sign = (b >> 16) & 0x8000
    a = b & 0x7FFFFFFF
    if a >= 0x7F800000:  # inf, or NaN (its top mantissa bits kept, and kept a NaN)
        h = 0x7C00 | ((a & 0x7FFFFF) >> 13)
        if h == 0x7C00 and a != 0x7F800000:
            h += 1
        return sign | h
    if a >= 0x47800000:  # >= 65536: beyond float16's range
        return sign | 0x7C00
    if a < 0x38800000:  # below float16's smallest normal (2**-14): subnormal or zero
        if a < 0x33000000:  # below 2**-25: rounds to zero
            return sign
        m = (a & 0x7FFFFF) | 0x800000
        shift = 126 - (a >> 23)
        h = m >> shift
        rem = m & ((1 << shift) - 1)
        half = 1 << (shift - 1)
        if rem > half or (rem == half and (h & 1) == 1):
            h += 1
        return sign | h
    h = (a >> 13) - (112 << 10)  # exponent rebiased from 127 to 15, the top 10 mantissa bits
    rem = a & 0x1FFF
    if rem > 0x1000 or (rem == 0x1000 and (h & 1) == 1):
        h += 1  # a carry into the exponent is right (65520 and up round to inf)
    return sign | h


@_njit_inline
def _crc_update(crc, data, lo, hi):  # pragma: no cover
    for i in range(lo, hi):
        crc = _CRC_TABLE[(crc ^ data[i]) & 0xFF] ^ (crc >> 8)
    return crc


@_njit
def encode_kernel(values, n, sender, tick, code, pad):  # pragma: no cover
    """:func:`.wire.encode_message`'s bytes for ``values[:n]`` (float32, contiguous, finite and
    within the payload bound: the caller checked them), sent by ``sender`` at ``tick``, with
    header byte 3 ``code`` (``wire.ENCODING_CODES``, the payload format in its high bits) and
    ``pad`` zero bytes after the 16-byte header."""
    item = 2 if (code & _CODE_MASK) == _F16 else 4
    hb = HEADER_SIZE + pad
    out = np.zeros(hb + n * item, np.uint8)
    out[0], out[1], out[2], out[3] = _MAGIC0, _MAGIC1, WIRE_VERSION, code
    out[4], out[5] = sender & 0xFF, (sender >> 8) & 0xFF
    out[6], out[7] = n & 0xFF, (n >> 8) & 0xFF
    for k in range(4):
        out[8 + k] = (tick >> (8 * k)) & 0xFF
    bits = values.view(np.uint32)
    for i in range(n):
        b = np.int64(bits[i])
        if item == 2:
            h = half_bits(b)
            out[hb + 2 * i], out[hb + 2 * i + 1] = h & 0xFF, h >> 8
        else:
            for k in range(4):
                out[hb + 4 * i + k] = (b >> (8 * k)) & 0xFF
    crc = _crc_update(np.int64(0xFFFFFFFF), out, 0, HEADER_SIZE - 4)
    crc = _crc_update(crc, out, hb, out.shape[0]) ^ 0xFFFFFFFF
    for k in range(4):
        out[12 + k] = (crc >> (8 * k)) & 0xFF
    return out


@_njit
def builtin_message_kernel(vis, threshold, pos, yaw, speed, kind, length, width, height, actor_id, ox, oy, oyaw,
                           max_rows, wrap_ids, sender, tick, code, pad):  # pragma: no cover
    """The built-in ``share_objects`` message of the unit at ``(ox, oy, oyaw)``: the actors with
    ``vis >= threshold`` as object rows (``jit_perception.seen_rows_kernel``, nearest first), the
    first ``max_rows`` of them, track ids modulo 2048 when ``wrap_ids`` (float16), encoded by
    :func:`encode_kernel`. Returns the message bytes, or no bytes when the unit sees nothing."""
    rows = seen_rows_kernel(vis, threshold, pos, yaw, speed, kind, length, width, height, actor_id, ox, oy, oyaw)
    k = min(rows.shape[0], max_rows)
    if k == 0:
        return np.zeros(0, np.uint8)
    flat = np.empty(k * NUM_OBJECT_FIELDS, np.float32)
    for r in range(k):
        for f in range(NUM_OBJECT_FIELDS):
            flat[r * NUM_OBJECT_FIELDS + f] = rows[r, f]
        if wrap_ids:
            j = r * NUM_OBJECT_FIELDS + _TRACK_ID_COL
            flat[j] = flat[j] % _TRACK_MOD
    return encode_kernel(flat, k * NUM_OBJECT_FIELDS, sender, tick, code, pad)


@_njit_inline
def float_bits(h):  # pragma: no cover
    """float32 bits (int64) of the float16 with bits ``h``: exact, as NumPy's ``astype``
    (subnormals normalized, infinities and NaN payloads kept)."""
    sign = (h & 0x8000) << 16
    e = (h >> 10) & 0x1F
    m = h & 0x3FF
    if e == 0:
        if m == 0:
            return sign
        e = 113
        while (m & 0x400) == 0:
            m <<= 1
            e -= 1
        return sign | (e << 23) | ((m & 0x3FF) << 13)
    if e == 31:
        return sign | 0x7F800000 | (m << 13)
    return sign | ((e + 112) << 23) | (m << 13)


@_njit
def decode_kernel(data, header_bytes):  # pragma: no cover
    """:func:`.wire.decode_message` of the message bytes ``data`` (uint8): ``(ok, sender, tick,
    payload float32)``; ``ok`` is false where the codec would raise (the caller then lets it name
    the problem). The payload format is header byte 3's high bits (``data[3] >> FORMAT_SHIFT``)."""
    none = np.zeros(0, np.float32)
    n = data.shape[0]
    if n < header_bytes or n < HEADER_SIZE:
        return False, 0, 0, none
    if data[0] != _MAGIC0 or data[1] != _MAGIC1 or data[2] != WIRE_VERSION:
        return False, 0, 0, none
    code = data[3] & _CODE_MASK
    if (code != _F16 and code != _F32) or (data[3] >> FORMAT_SHIFT) > _MAX_FORMAT:
        return False, 0, 0, none
    item = 2 if code == _F16 else 4
    sender = np.int64(data[4]) | (np.int64(data[5]) << 8)
    length = np.int64(data[6]) | (np.int64(data[7]) << 8)
    tick = np.int64(0)
    crc = np.int64(0)
    for k in range(4):
        tick |= np.int64(data[8 + k]) << (8 * k)
        crc |= np.int64(data[12 + k]) << (8 * k)
    if n != header_bytes + length * item:
        return False, 0, 0, none
    for i in range(HEADER_SIZE, header_bytes):
        if data[i] != 0:
            return False, 0, 0, none
    c = _crc_update(np.int64(0xFFFFFFFF), data, 0, HEADER_SIZE - 4)
    if _crc_update(c, data, header_bytes, n) ^ 0xFFFFFFFF != crc:
        return False, 0, 0, none
    payload = np.empty(length, np.float32)
    bits = payload.view(np.uint32)
    for i in range(length):
        j = header_bytes + item * i
        if item == 2:
            bits[i] = np.uint32(float_bits(np.int64(data[j]) | (np.int64(data[j + 1]) << 8)))
        else:
            b = np.int64(0)
            for k in range(4):
                b |= np.int64(data[j + k]) << (8 * k)
            bits[i] = np.uint32(b)
    return True, sender, tick, payload
