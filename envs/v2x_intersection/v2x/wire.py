"""The V2X wire format: message bytes (:func:`encode_message`, :func:`decode_message`) and the
"share objects" payload (:func:`pack_objects`, :func:`unpack_objects`).

:mod:`.channel` sends these bytes between the RSU and the ego; this module knows nothing of
latency, loss or bandwidth.

Wire format (little endian). A message is a fixed header followed by the payload:

=======  ======  ==========================================================================
offset   type    field
=======  ======  ==========================================================================
0        2s      magic ``b"VX"``
2        uint8   format version (:data:`WIRE_VERSION`, currently 1)
3        uint8   low 4 bits: encoding code, 1 = float16, 2 = float32 (:data:`ENCODING_CODES`);
                 high 4 bits: payload format, 0 = object list, 1 = raw (:data:`PAYLOAD_FORMATS`)
4        uint16  sender id (RSU unit id, 0..65535)
6        uint16  payload length in floats (0..65535)
8        uint32  tick at which the message was sent (simulation ticks of ``dt`` seconds)
12       uint32  CRC-32 (zlib) of header bytes 0..11 followed by the payload bytes
16       ...     reserved zero padding up to ``header_bytes`` (only if ``header_bytes > 16``)
hdr      L*size  payload: ``L`` floats in the declared encoding (2 or 4 bytes each)
=======  ======  ==========================================================================

So every message costs exactly ``header_bytes + length * itemsize`` bytes on air, with
``header_bytes = 16`` by default (:data:`HEADER_SIZE`). A ``length`` of 0 means "say nothing":
no message is sent, no header, 0 bytes.

Payload formats (:data:`PAYLOAD_FORMATS`): the channel carries and counts every payload alike, as
opaque floats; the format only says how a receiver may read it. ``objects`` (0) is the
"share objects" object list (:func:`pack_objects`), which the ego decodes into its
``v2x_objects``; ``raw`` (1) is any other payload (a custom roadside policy's own message), which
the ego receives as is. An object-list message has the same bytes as before the format existed
(format 0 leaves byte 3 as the encoding code alone).
"""

from __future__ import annotations

import numbers
import struct
import zlib

import numpy as np

__all__ = [
    "ENCODING_CODES",
    "FLOAT16_TRACK_ID_MODULUS",
    "HEADER_SIZE",
    "MAGIC",
    "NUM_OBJECT_FIELDS",
    "OBJECT_FIELDS",
    "PAYLOAD_LIMIT",
    "WIRE_VERSION",
    "check_header",
    "FORMAT_OBJECTS",
    "FORMAT_RAW",
    "PAYLOAD_FORMATS",
    "check_format",
    "decode_frame",
    "decode_message",
    "encode_message",
    "max_objects",
    "pack_objects",
    "pack_rows",
    "unpack_objects",
    "wrap_track_ids",
]

MAGIC = b"VX"
WIRE_VERSION = 1
#: Wire codes of the payload encodings.
ENCODING_CODES: dict[str, int] = {"float16": 1, "float32": 2}
_CODE_TO_DTYPE: dict[int, np.dtype] = {1: np.dtype("<f2"), 2: np.dtype("<f4")}
_ENCODING_DTYPES: dict[str, np.dtype] = {"float16": np.dtype("<f2"), "float32": np.dtype("<f4")}
#: Wire codes of the payload formats (high 4 bits of header byte 3; see the module docstring).
PAYLOAD_FORMATS: dict[str, int] = {"objects": 0, "raw": 1}
FORMAT_OBJECTS = PAYLOAD_FORMATS["objects"]
FORMAT_RAW = PAYLOAD_FORMATS["raw"]
FORMAT_SHIFT = 4  # the format's bits in header byte 3
_CODE_MASK = (1 << FORMAT_SHIFT) - 1  # the encoding's bits in header byte 3
_FORMAT_NAMES = {v: k for k, v in PAYLOAD_FORMATS.items()}

_HEADER = struct.Struct("<2sBBHHII")  # magic, version, encoding, sender, length, tick, crc32
_HEADER_NOCRC = struct.Struct("<2sBBHHI")
#: Size in bytes of the fixed part of the wire header (the minimum ``header_bytes``).
HEADER_SIZE = _HEADER.size  # 16
_MAX_U16 = 0xFFFF
_MAX_U32 = 0xFFFFFFFF

#: Bound on payload values (the ``Box`` of :func:`message_space`); inside float16's range (65504).
PAYLOAD_LIMIT = 1.0e4

#: Fields of one object in a "share objects" payload, in order. Positions and velocities are in
#: the sending RSU's frame (m, m/s), yaw in rad, sizes in m; ``class_id`` as in ``classes.py``
#: (8, ``EMERGENCY_VEHICLE``: an emergency vehicle with its siren on).
OBJECT_FIELDS: tuple[str, ...] = (
    "class_id",
    "x",
    "y",
    "yaw",
    "length",
    "width",
    "height",
    "vx",
    "vy",
    "track_id",
)
NUM_OBJECT_FIELDS = len(OBJECT_FIELDS)
_TRACK_ID_COL = OBJECT_FIELDS.index("track_id")
#: float16 represents every integer in ``[0, 2048]`` exactly; track ids wrap modulo this.
FLOAT16_TRACK_ID_MODULUS = 2048


def _is_int(x: object) -> bool:
    """True for Python/numpy integers, False for bools (fast path for plain ``int``)."""
    t = type(x)
    if t is int:
        return True
    if t is bool:
        return False
    return isinstance(x, numbers.Integral) and not isinstance(x, bool | np.bool_)


# --------------------------------------------------------------------------------------------
# Codec
# --------------------------------------------------------------------------------------------


def encode_message(
    sender_id: int,
    tick: int,
    payload: np.ndarray,
    encoding: str = "float16",
    header_bytes: int = HEADER_SIZE,
    fmt: int = FORMAT_OBJECTS,
) -> bytes:
    """Serialize one message to bytes (see the wire format in the module docstring).

    Args:
        sender_id: Sender (RSU unit) id in ``[0, 65535]``.
        tick: Tick at which the message is sent, in ``[0, 2**32 - 1]``.
        payload: ``(L,)`` floats, all finite, ``L <= 65535``; encoded with round-to-nearest.
        encoding: ``"float16"`` or ``"float32"``.
        header_bytes: Total header size; bytes beyond :data:`HEADER_SIZE` are zero padding.
        fmt: Payload format code (:data:`PAYLOAD_FORMATS`; default the object list).

    Returns:
        ``header_bytes + L * itemsize`` bytes.

    Raises:
        ValueError: For out-of-range ids/ticks/lengths, an unknown encoding or format, a payload
            that is not 1-D, non-finite values, or values that overflow the encoding (float16 max
            is 65504).
    """
    dtype = _ENCODING_DTYPES.get(encoding)
    if dtype is None:
        raise ValueError(
            f"unknown encoding {encoding!r}; expected one of {tuple(_ENCODING_DTYPES)}"
        )
    check_header(sender_id, tick)
    fmt = check_format(fmt)
    if header_bytes < HEADER_SIZE:
        raise ValueError(f"header_bytes must be >= {HEADER_SIZE}, got {header_bytes}")
    p = np.asarray(payload)
    if p.ndim != 1:
        raise ValueError(f"payload must be 1-D (L,), got shape {p.shape}")
    if p.shape[0] > _MAX_U16:
        raise ValueError(f"payload too long: {p.shape[0]} floats > {_MAX_U16}")
    if p.dtype.kind not in "fiu":
        raise ValueError(f"payload must hold floats, got dtype {p.dtype}")
    with np.errstate(over="ignore", invalid="ignore"):
        enc = p.astype(dtype)
    if not np.isfinite(enc).all():
        if not np.isfinite(p).all():
            raise ValueError("payload contains NaN or inf")
        raise ValueError(f"payload values overflow {encoding} (max abs {float(np.abs(p).max())})")
    code = ENCODING_CODES[encoding] | (fmt << FORMAT_SHIFT)
    return _serialize(sender_id, tick, enc, code, header_bytes - HEADER_SIZE)


def check_format(fmt: object) -> int:
    """``fmt`` as a Python int if it is a payload format code (:data:`PAYLOAD_FORMATS`); raise
    ``ValueError`` naming the known formats otherwise."""
    if isinstance(fmt, np.ndarray) and fmt.ndim == 0 and fmt.dtype.kind in "iu":
        fmt = fmt.item()
    if not _is_int(fmt) or int(fmt) not in _FORMAT_NAMES:
        known = ", ".join(f"{v} = {k}" for k, v in PAYLOAD_FORMATS.items())
        raise ValueError(f"message format must be a payload format code ({known}), got {fmt!r}")
    return int(fmt)


def check_header(sender_id: int, tick: int) -> None:
    """Raise ``ValueError`` unless ``sender_id`` is an integer that fits the header's uint16 and
    ``tick`` one that fits its uint32."""
    if not _is_int(sender_id) or not 0 <= sender_id <= _MAX_U16:
        raise ValueError(f"sender_id must be an integer in [0, {_MAX_U16}], got {sender_id!r}")
    if not _is_int(tick) or not 0 <= tick <= _MAX_U32:
        raise ValueError(f"tick must be an integer in [0, {_MAX_U32}], got {tick!r}")


def _serialize(sender_id: int, tick: int, enc: np.ndarray, code: int, pad: int) -> bytes:
    """Header + payload bytes of an already encoded, already checked ``(L,)`` payload."""
    body = enc.tobytes()
    h = _HEADER_NOCRC.pack(MAGIC, WIRE_VERSION, code, sender_id, enc.shape[0], tick)
    crc = zlib.crc32(body, zlib.crc32(h))
    return b"".join((h, crc.to_bytes(4, "little"), b"\x00" * pad, body))


def decode_message(
    data: bytes | bytearray | memoryview, header_bytes: int = HEADER_SIZE
) -> tuple[int, int, np.ndarray]:
    """``(sender_id, tick, payload)`` of :func:`decode_frame` (the payload format left out)."""
    return decode_frame(data, header_bytes)[:3]


def decode_frame(
    data: bytes | bytearray | memoryview, header_bytes: int = HEADER_SIZE
) -> tuple[int, int, np.ndarray, int]:
    """Parse bytes produced by :func:`encode_message`, checking the header and checksum.

    Args:
        data: The serialized message.
        header_bytes: Header size the message was encoded with.

    Returns:
        ``(sender_id, tick, payload, fmt)`` with ``payload`` a new ``(L,)`` float32 array and
        ``fmt`` its format code (:data:`PAYLOAD_FORMATS`).

    Raises:
        ValueError: Naming the problem: truncated data, bad magic, unsupported version, unknown
            encoding or payload format, non-zero padding, size mismatch (truncated or trailing
            payload bytes), or checksum mismatch (corrupt message).
    """
    n = len(data)
    if n < header_bytes or n < HEADER_SIZE:
        raise ValueError(
            f"truncated message: {n} bytes, shorter than the {header_bytes}-byte header"
        )
    magic, version, code, sender_id, length, tick, crc = _HEADER.unpack_from(data, 0)
    if magic != MAGIC:
        raise ValueError(f"bad magic {bytes(magic)!r}, expected {MAGIC!r}: not a V2X message")
    if version != WIRE_VERSION:
        raise ValueError(f"unsupported wire version {version} (this codec reads {WIRE_VERSION})")
    fmt = code >> FORMAT_SHIFT
    if fmt not in _FORMAT_NAMES:
        raise ValueError(f"unknown payload format {fmt} in header (known: {PAYLOAD_FORMATS})")
    dtype = _CODE_TO_DTYPE.get(code & _CODE_MASK)
    if dtype is None:
        raise ValueError(f"unknown encoding code {code & _CODE_MASK} in header")
    expected = header_bytes + length * dtype.itemsize
    if n != expected:
        what = "truncated" if n < expected else "trailing bytes in"
        raise ValueError(
            f"size mismatch ({what} message): header declares {length} floats = {expected} bytes, got {n}"
        )
    mv = memoryview(data)
    if header_bytes > HEADER_SIZE and any(mv[HEADER_SIZE:header_bytes]):
        raise ValueError("corrupt message: non-zero header padding")
    body = mv[header_bytes:]
    if zlib.crc32(body, zlib.crc32(mv[: HEADER_SIZE - 4])) != crc:
        raise ValueError("checksum mismatch: corrupt message")
    payload = np.frombuffer(body, dtype=dtype).astype(np.float32)
    return sender_id, tick, payload, fmt

def _check_used(payload: np.ndarray, length: int) -> None:
    """Raise if the used part ``payload[:length]`` holds NaN/inf or leaves the Box bound."""
    if length == 0:
        return
    used = payload[:length]
    mx = np.abs(used).max()
    if not mx <= PAYLOAD_LIMIT:  # catches NaN as well
        if not np.isfinite(used).all():
            bad = int(np.flatnonzero(~np.isfinite(used))[0])
            raise ValueError(f"message payload contains NaN/inf in its used part (index {bad})")
        raise ValueError(
            f"message payload value {float(mx)} out of range: |value| must be <= {PAYLOAD_LIMIT}"
        )


# --------------------------------------------------------------------------------------------
# Object lists <-> payload
# --------------------------------------------------------------------------------------------


def max_objects(max_payload_floats: int) -> int:
    """How many objects of :data:`NUM_OBJECT_FIELDS` floats fit in a payload."""
    return max_payload_floats // NUM_OBJECT_FIELDS


def pack_objects(
    objs: np.ndarray, max_payload_floats: int = 512, encoding: str = "float16"
) -> tuple[int, np.ndarray]:
    """Pack an object list into a message payload (the "share objects" RSU policy).

    Objects are written row by row, :data:`OBJECT_FIELDS` order, and truncated to the
    ``max_objects(max_payload_floats)`` first rows: the caller orders them by priority (e.g. by
    distance to the ego). The number packed is ``length // NUM_OBJECT_FIELDS``.

    Precision: the whole message uses the channel's single ``encoding``. We keep float16 as the
    default rather than a float32 side channel for positions, because objects must be sent in the
    RSU frame, where coordinates are below 200 m: float16's step is 0.0625 m in [64, 128) m and
    0.125 m in [128, 256) m, so the rounding error is <= 0.0625 m (relative error <= 2**-11), far
    below detection noise, at half the bytes. Sending world coordinates (up to 1e4 m) in float16
    would cost up to 4 m of error, so do not. Angles lose at most ~1e-3 rad, sizes and speeds
    < 2**-11 relative. Track ids: float16 holds integers exactly only up to 2048, so with float16
    ``track_id`` is wrapped modulo :data:`FLOAT16_TRACK_ID_MODULUS` (harmless for association
    between consecutive messages with fewer than 2048 live tracks). Use ``encoding="float32"``
    (channel config) where more precision is needed.

    Args:
        objs: ``(K, NUM_OBJECT_FIELDS)`` floats, positions/velocities in the RSU frame.
        max_payload_floats: Payload capacity (``ChannelConfig.max_payload_floats``).
        encoding: The channel's encoding (only changes the track id wrapping).

    Returns:
        ``(length, payload)``: ``length = min(K, max_objects) * NUM_OBJECT_FIELDS`` and a
        ``(max_payload_floats,)`` float32 payload, zero beyond ``length``: a valid message action.

    Raises:
        ValueError: If ``objs`` is not ``(K, NUM_OBJECT_FIELDS)``, holds NaN/inf, or values beyond
            :data:`PAYLOAD_LIMIT`.
    """
    a = np.asarray(objs, dtype=np.float32)
    if a.ndim != 2 or a.shape[1] != NUM_OBJECT_FIELDS:
        raise ValueError(f"objs must have shape (K, {NUM_OBJECT_FIELDS}), got {a.shape}")
    if encoding not in _ENCODING_DTYPES:
        raise ValueError(f"unknown encoding {encoding!r}")
    length, payload = pack_rows(a, max_payload_floats, encoding)
    _check_used(payload, length)
    return length, payload


def pack_rows(a: np.ndarray, max_payload_floats: int, encoding: str) -> tuple[int, np.ndarray]:
    """:func:`pack_objects` without its checks (``a``: ``(K, NUM_OBJECT_FIELDS)`` float32, finite)."""
    k = min(a.shape[0], max_objects(max_payload_floats))
    length = k * NUM_OBJECT_FIELDS
    payload = np.zeros(max_payload_floats, np.float32)
    if k:
        rows = a[:k]
        if encoding == "float16":
            rows = rows.copy()
            wrap_track_ids(rows)
        payload[:length] = rows.reshape(-1)
    return length, payload


def wrap_track_ids(rows: np.ndarray) -> None:
    """In place on ``(K, NUM_OBJECT_FIELDS)`` rows: track ids modulo
    :data:`FLOAT16_TRACK_ID_MODULUS`, as float16 messages carry them."""
    rows[:, _TRACK_ID_COL] = np.mod(rows[:, _TRACK_ID_COL], FLOAT16_TRACK_ID_MODULUS)


def unpack_objects(payload: np.ndarray, length: int) -> np.ndarray:
    """Inverse of :func:`pack_objects`.

    Args:
        payload: ``(>= length,)`` floats (e.g. a decoded message payload).
        length: Used floats; a multiple of :data:`NUM_OBJECT_FIELDS`.

    Returns:
        ``(length // NUM_OBJECT_FIELDS, NUM_OBJECT_FIELDS)`` float32 array (a copy).
    """
    p = np.asarray(payload)
    if p.ndim != 1 or p.shape[0] < length or length < 0:
        raise ValueError(f"payload of shape {p.shape} cannot hold {length} floats")
    if length % NUM_OBJECT_FIELDS:
        raise ValueError(
            f"length {length} is not a multiple of NUM_OBJECT_FIELDS={NUM_OBJECT_FIELDS}"
        )
    return p[:length].astype(np.float32).reshape(-1, NUM_OBJECT_FIELDS)
