"""The V2X channel between the roadside unit (RSU) and the ego vehicle.

The RSU's action in the RL environments *is* its message: a typed, fixed-size action
(:func:`message_space`) holding a used length, a float payload and the payload's format (an
object list, which the ego decodes, or a raw payload of the sender's own design; the channel
treats both as opaque floats, :data:`PAYLOAD_FORMATS`). The :class:`Channel`
serializes every message to real bytes (:func:`encode_message`), counts them, and applies
latency, radio loss and a bandwidth cap before the ego receives and decodes it. **Bandwidth
(BPS) is always measured here**, from the serialized byte counts, never reported by a method
about itself (``METRICS.md``, "Bandwidth (BPS)").

The bytes on air are :mod:`.wire`'s format (header, CRC-32, float16 / float32 payload).

Time convention: ticks are integers; tick ``t`` is simulated time ``t * dt`` seconds. The
channel's clock is the largest tick it has seen in :meth:`Channel.send`,
:meth:`Channel.receive` or :meth:`Channel.advance` since :meth:`Channel.reset`; ticks must
never go backwards.
"""

from __future__ import annotations

import math
import numbers
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from gymnasium import spaces

from ..core.jit import HAVE_JIT
from .jit_wire import decode_kernel
from .wire import (
    _ENCODING_DTYPES,
    _MAX_U16,
    ENCODING_CODES,
    FORMAT_OBJECTS,
    FORMAT_RAW,
    FORMAT_SHIFT,
    HEADER_SIZE,
    MAGIC,
    NUM_OBJECT_FIELDS,
    OBJECT_FIELDS,
    PAYLOAD_FORMATS,
    PAYLOAD_LIMIT,
    WIRE_VERSION,
    _check_used,
    _is_int,
    _serialize,
    check_format,
    check_header,
    decode_frame,
    decode_message,
    encode_message,
    max_objects,
    pack_objects,
    unpack_objects,
)

__all__ = [
    "ENCODING_CODES",
    "FORMAT_OBJECTS",
    "FORMAT_RAW",
    "HEADER_SIZE",
    "MAGIC",
    "NUM_OBJECT_FIELDS",
    "OBJECT_FIELDS",
    "PAYLOAD_FORMATS",
    "PAYLOAD_LIMIT",
    "WIRE_VERSION",
    "Channel",
    "ChannelConfig",
    "Delivery",
    "decode_message",
    "empty_message",
    "encode_message",
    "max_objects",
    "message_format",
    "message_space",
    "pack_objects",
    "unpack_objects",
    "validate_message",
]

# --------------------------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ChannelConfig:
    """Parameters of the RSU -> ego V2X channel.

    Attributes:
        latency_ticks: Delivery delay in ticks: a message sent at tick ``t`` is delivered to the
            ego's observation at tick ``t + latency_ticks`` (0 = the same tick, provided the
            environment sends before it receives). Integer ``>= 0``.
        loss_prob: Probability in ``[0, 1]`` that a transmitted message is lost on the radio.
            Lost messages were transmitted, so their bytes count as sent.
        bandwidth_bytes_per_s: Cap on bytes on air per second, or ``None`` for unlimited. Enforced
            over a sliding window of the last ``round(1 / dt)`` ticks (see :class:`Channel`); a
            message that does not fit is dropped before transmission and its bytes are not
            counted as sent.
        header_bytes: Fixed per-message header size in bytes, counted for every transmitted
            message. At least :data:`HEADER_SIZE` (16: magic, version, encoding, sender id,
            length, tick, CRC-32; see the module docstring); any extra is reserved zero padding
            that is really serialized (e.g. to model a larger link-layer header).
        max_payload_floats: Maximum floats per message (the payload size of the action space),
            in ``[1, 65535]``.
        encoding: Wire encoding of payload floats: ``"float16"`` (2 bytes) or ``"float32"``
            (4 bytes).
        dt: Simulation tick length in seconds (> 0).
    """

    latency_ticks: int = 1
    loss_prob: float = 0.0
    bandwidth_bytes_per_s: float | None = None
    header_bytes: int = HEADER_SIZE
    max_payload_floats: int = 512
    encoding: str = "float16"
    dt: float = 0.1

    def __post_init__(self) -> None:
        def bad(field: str, value: object, need: str) -> ValueError:
            return ValueError(f"ChannelConfig.{field} must be {need}, got {value!r}")

        if not _is_int(self.latency_ticks) or self.latency_ticks < 0:
            raise bad("latency_ticks", self.latency_ticks, "an integer >= 0")
        lp = self.loss_prob
        if (
            not isinstance(lp, numbers.Real)
            or isinstance(lp, bool)
            or not math.isfinite(lp)
            or not 0.0 <= lp <= 1.0
        ):
            raise bad("loss_prob", lp, "a number in [0, 1]")
        bw = self.bandwidth_bytes_per_s
        if bw is not None and (
            not isinstance(bw, numbers.Real)
            or isinstance(bw, bool)
            or not math.isfinite(bw)
            or bw <= 0
        ):
            raise bad("bandwidth_bytes_per_s", bw, "None or a finite number > 0")
        if not _is_int(self.header_bytes) or not HEADER_SIZE <= self.header_bytes <= _MAX_U16:
            raise bad(
                "header_bytes", self.header_bytes, f"an integer in [{HEADER_SIZE}, {_MAX_U16}]"
            )
        if not _is_int(self.max_payload_floats) or not 1 <= self.max_payload_floats <= _MAX_U16:
            raise bad(
                "max_payload_floats", self.max_payload_floats, f"an integer in [1, {_MAX_U16}]"
            )
        if self.encoding not in _ENCODING_DTYPES:
            raise bad("encoding", self.encoding, f"one of {tuple(_ENCODING_DTYPES)}")
        dt = self.dt
        if (
            not isinstance(dt, numbers.Real)
            or isinstance(dt, bool)
            or not math.isfinite(dt)
            or dt <= 0
        ):
            raise bad("dt", dt, "a finite number of seconds > 0")

    @property
    def itemsize(self) -> int:
        """Bytes per payload float on the wire (2 for float16, 4 for float32)."""
        return _ENCODING_DTYPES[self.encoding].itemsize

    @property
    def window_ticks(self) -> int:
        """Ticks in the one-second window used by the bandwidth cap and ``peak_bps``."""
        return max(1, round(1.0 / self.dt))

    def message_bytes(self, length: int) -> int:
        """Bytes on air for a message of ``length`` floats (0 if ``length == 0``)."""
        return 0 if length == 0 else self.header_bytes + length * self.itemsize


# --------------------------------------------------------------------------------------------
# The RSU message action
# --------------------------------------------------------------------------------------------


def message_space(config: ChannelConfig) -> spaces.Dict:
    """The RSU's action space: its message.

    ``{"length": Discrete(max_payload_floats + 1), "payload": Box(-1e4, 1e4, (max_payload_floats,),
    float32), "format": Discrete(2)}``. Only ``payload[:length]`` is sent; the rest is ignored
    (keep it zero). ``length == 0`` means "send nothing" (0 bytes). The ``+-1e4`` bound
    (:data:`PAYLOAD_LIMIT`) stays inside float16's finite range. ``format``
    (:data:`PAYLOAD_FORMATS`): 0 = an object list (:func:`pack_objects`; the ego decodes it into
    ``v2x_objects``), 1 = a raw payload (the ego gets it only as ``v2x_payload``); a message
    without the key is an object list, as before the key existed (:func:`message_format`).
    """
    m = config.max_payload_floats
    return spaces.Dict(
        {
            "length": spaces.Discrete(m + 1),
            "payload": spaces.Box(-PAYLOAD_LIMIT, PAYLOAD_LIMIT, (m,), np.float32),
            "format": spaces.Discrete(len(PAYLOAD_FORMATS)),
        }
    )


def empty_message(config: ChannelConfig) -> dict[str, object]:
    """A valid "send nothing" action: ``length`` 0 and an all-zero payload."""
    return {"length": 0, "payload": np.zeros(config.max_payload_floats, np.float32),
            "format": FORMAT_OBJECTS}


def message_format(action: Mapping) -> int:
    """The payload format code of an RSU message action (:data:`PAYLOAD_FORMATS`):
    ``action["format"]``, or :data:`FORMAT_OBJECTS` when it has no ``"format"`` key.

    Raises:
        ValueError: a format that is not a known code (the message lists them).
    """
    fmt = action.get("format", FORMAT_OBJECTS)
    return fmt if type(fmt) is int and fmt in _FORMAT_CODES else check_format(fmt)


_FORMAT_CODES = frozenset(PAYLOAD_FORMATS.values())


def _check_length(length: object, max_floats: int) -> int:
    if isinstance(length, np.ndarray) and length.ndim == 0:
        length = length.item() if length.dtype.kind in "iu" else length
    if not _is_int(length):
        raise ValueError(
            f"message length must be an integer, got {length!r} ({type(length).__name__})"
        )
    if length < 0:
        raise ValueError(f"message length must be >= 0, got {length}")
    if length > max_floats:
        raise ValueError(
            f"oversized message: length {length} exceeds the limit of max_payload_floats={max_floats}"
        )
    return int(length)



def validate_message(action: Mapping, config: ChannelConfig) -> tuple[int, np.ndarray]:
    """Check an RSU message action against :func:`message_space`.

    Args:
        action: ``{"length": int, "payload": (max_payload_floats,) float array}``.
        config: The channel configuration.

    Returns:
        ``(length, payload)`` with ``length`` a Python int and ``payload`` the given array
        (converted to float32 if it was float64).

    Raises:
        ValueError: Naming the problem: missing keys, non-integer or negative length, oversized
            message (length > max_payload_floats; the message names the limit), wrong payload
            shape, wrong dtype kind (not floating point), NaN/inf or out-of-range values in
            ``payload[:length]``.
    """
    if not isinstance(action, Mapping):
        raise ValueError(
            f"message must be a dict with 'length' and 'payload', got {type(action).__name__}"
        )
    missing = [k for k in ("length", "payload") if k not in action]
    if missing:
        raise ValueError(f"message is missing key(s) {missing}")
    m = config.max_payload_floats
    length = _check_length(action["length"], m)
    payload = action["payload"]
    if not isinstance(payload, np.ndarray):
        raise ValueError(f"message payload must be a numpy array, got {type(payload).__name__}")
    if payload.shape != (m,):
        raise ValueError(f"message payload has wrong shape {payload.shape}, expected ({m},)")
    if payload.dtype.kind != "f":
        raise ValueError(
            f"message payload has wrong dtype {payload.dtype}: expected floating point"
        )
    if payload.dtype != np.float32:
        payload = payload.astype(np.float32)
    _check_used(payload, length)
    return length, payload


# --------------------------------------------------------------------------------------------
# The channel
# --------------------------------------------------------------------------------------------


class Delivery(NamedTuple):
    """A message as :meth:`Channel.deliver` hands it over: who sent it, when, what it holds, and
    the payload's format code (:data:`PAYLOAD_FORMATS`)."""

    sender: int
    tick: int
    payload: np.ndarray
    format: int


class Channel:
    """RSU -> ego channel: serializes, counts, delays, loses and rate-limits messages.

    Per :meth:`send`, in order:

    1. ``length == 0``: nothing is sent (0 bytes, no header, nothing counted but the clock).
    2. The message is serialized (:func:`encode_message`); its size is
       ``header_bytes + length * itemsize``.
    3. Bandwidth cap (if set): a sliding window over the last ``W = round(1 / dt)`` ticks
       (the current tick included) may carry at most ``bandwidth_bytes_per_s * W * dt`` bytes
       (= the cap per second at ``dt = 0.1``). A message that does not fit in what remains is
       dropped whole before transmission: counted in ``messages_dropped_bandwidth`` and
       ``bytes_dropped_bandwidth``, **not** in the sent bytes. No partial sends, no queueing.
       Hence ``peak_bps <= bandwidth_bytes_per_s`` always holds.
    4. The message is transmitted: its bytes count in ``bytes_sent_total`` and BPS.
    5. Radio loss: if ``loss_prob > 0`` one uniform draw from the channel's ``rng`` (and only
       from it) decides loss; lost messages **do** count as sent bytes (they were on air), in
       ``messages_lost``. The draw is made for each transmitted message and for no other reason,
       so the same seed and the same sends give the same losses.
    6. Otherwise it is queued for delivery at tick ``tick + latency_ticks``.

    :meth:`receive` decodes and returns every queued message due at or before the given tick,
    oldest first; each is returned exactly once.

    Statistics (:meth:`stats`): ``bps = bytes_sent_total / ((now + 1) * dt)`` where ``now`` is
    the current tick: elapsed time counts ticks 0..now inclusive, each ``dt`` seconds long (0.0
    before any tick). ``peak_bps`` is the maximum bytes sent in any window of ``W`` consecutive
    ticks (windows overlapping tick 0 included), divided by ``W * dt`` seconds.

    Args:
        config: Channel parameters.
        rng: Generator used for the loss draws only.
    """

    def __init__(self, config: ChannelConfig, rng: np.random.Generator):
        if not isinstance(config, ChannelConfig):
            raise TypeError(f"config must be a ChannelConfig, got {type(config).__name__}")
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        self.config = config
        self.rng = rng
        self._W = config.window_ticks
        self._window_s = self._W * config.dt
        bw = config.bandwidth_bytes_per_s
        self._cap = None if bw is None else bw * self._window_s
        self._dtype = _ENCODING_DTYPES[config.encoding]
        self._code = ENCODING_CODES[config.encoding]
        self._pad = config.header_bytes - HEADER_SIZE
        self.reset()

    def reset(self) -> None:
        """Clear the queue, the clock and all counters (the rng is left as is)."""
        self._pending: deque[tuple[int, int, bytes]] = deque()  # (due_tick, n_bytes, data)
        self._now = -1
        self._ring = [0] * self._W  # bytes sent per tick, indexed tick % W
        self._wsum = 0
        self._peak = 0
        self._bytes_sent = 0
        self._bytes_delivered = 0
        self._bytes_dropped = 0
        self._n_sent = 0
        self._n_lost = 0
        self._n_dropped = 0
        self._n_delivered = 0
        self._last_bytes = 0
        self._last_delivered: tuple[int, int, np.ndarray] | None = None

    # ---------------------------------------------------------------------------------- clock
    @property
    def now(self) -> int:
        """The current tick (-1 before any tick since reset)."""
        return self._now

    def advance(self, tick: int) -> None:
        """Move the clock to ``tick`` (no-op if already there); ticks may not go backwards."""
        now = self._now
        if tick == now:
            return
        if type(tick) is not int and not _is_int(tick):
            raise ValueError(f"tick must be an integer, got {tick!r}")
        if tick < now:
            raise ValueError(f"tick went backwards: {tick} < current tick {now}")
        if tick < 0:
            raise ValueError(f"tick must be >= 0, got {tick}")
        ring = self._ring
        W = self._W
        if tick - now >= W:
            for i in range(W):
                ring[i] = 0
            self._wsum = 0
        else:
            for t in range(now + 1, tick + 1):
                i = t % W
                self._wsum -= ring[i]
                ring[i] = 0
        self._now = tick

    # ----------------------------------------------------------------------------------- send
    def send(self, tick: int, sender_id: int, length: int, payload: np.ndarray,
             fmt: int = FORMAT_OBJECTS) -> int:
        """Send the first ``length`` floats of ``payload`` from ``sender_id`` at ``tick``.

        Args:
            tick: Current tick (non-decreasing across calls).
            sender_id: RSU unit id in ``[0, 65535]``.
            length: Floats to send, ``0..max_payload_floats``; 0 sends nothing.
            payload: ``(>= length,)`` floats; ``payload[:length]`` must be finite and within
                ``+-PAYLOAD_LIMIT``.
            fmt: the payload's format code (:data:`PAYLOAD_FORMATS`; carried in the header, so it
                costs no bytes).

        Returns:
            Bytes put on air: ``header_bytes + length * itemsize``, or 0 if ``length == 0`` or
            the message was dropped by the bandwidth cap (lost messages return their bytes).

        Raises:
            ValueError: Oversized/negative length, bad payload or format, or a tick earlier than
                the clock.
        """
        cfg = self.config
        length = _check_length(length, cfg.max_payload_floats)
        fmt = check_format(fmt)
        if length == 0:
            self.advance(tick)
            self._last_bytes = 0
            return 0
        p = payload if isinstance(payload, np.ndarray) else np.asarray(payload)
        if p.ndim != 1 or p.shape[0] < length:
            raise ValueError(f"payload of shape {p.shape} cannot hold a message of length {length}")
        if p.dtype.kind != "f":
            raise ValueError(f"message payload has wrong dtype {p.dtype}: expected floating point")
        _check_used(p, length)
        return self.send_valid(tick, sender_id, length, p, fmt)

    def send_valid(self, tick: int, sender_id: int, length: int, p: np.ndarray,
                   fmt: int = FORMAT_OBJECTS) -> int:
        """:meth:`send` without its payload checks: the caller guarantees ``length > 0``,
        ``p[:length]`` finite float32 within ``+-PAYLOAD_LIMIT`` and ``fmt`` a format code (e.g.
        after :func:`validate_message` and :func:`message_format`, or rows the world packed
        itself)."""
        self.advance(tick)
        check_header(sender_id, tick)
        # payload[:length] is finite and within +-PAYLOAD_LIMIT: the cast cannot overflow.
        code = self._code | (fmt << FORMAT_SHIFT)
        data = _serialize(sender_id, tick, p[:length].astype(self._dtype), code, self._pad)
        return self._transmit(tick, data)

    def send_encoded(self, tick: int, data: np.ndarray) -> int:
        """:meth:`send_valid` for a message already serialized by this channel's rules (the bytes of
        :func:`encode_message` with this config's encoding and header size, e.g. from
        ``jit_wire.builtin_message_kernel``; sender and tick checked by :func:`check_header`)."""
        self.advance(tick)
        return self._transmit(tick, data.tobytes())

    @property
    def wire_code(self) -> int:
        """The wire code of this channel's encoding (:data:`ENCODING_CODES`)."""
        return self._code

    @property
    def header_pad(self) -> int:
        """Zero bytes after the fixed 16-byte header (``header_bytes - HEADER_SIZE``)."""
        return self._pad

    def _transmit(self, tick: int, data: bytes) -> int:
        """Steps 3-6 of :meth:`send` for the serialized message ``data``."""
        cfg = self.config
        n = len(data)
        if self._cap is not None and self._wsum + n > self._cap:
            self._n_dropped += 1
            self._bytes_dropped += n
            self._last_bytes = 0
            return 0
        self._ring[tick % self._W] += n
        self._wsum += n
        if self._wsum > self._peak:
            self._peak = self._wsum
        self._bytes_sent += n
        self._n_sent += 1
        self._last_bytes = n
        lp = cfg.loss_prob
        if lp > 0.0 and self.rng.random() < lp:
            self._n_lost += 1
        else:
            self._pending.append((tick + cfg.latency_ticks, n, data))
        return n

    def send_action(self, tick: int, sender_id: int, action: Mapping) -> int:
        """Validate an RSU message action (:func:`validate_message`, :func:`message_format`) and
        :meth:`send` it."""
        length, payload = validate_message(action, self.config)
        fmt = message_format(action)
        if length == 0:
            return self.send(tick, sender_id, 0, payload)
        return self.send_valid(tick, sender_id, length, payload, fmt)

    # -------------------------------------------------------------------------------- receive
    def receive(self, tick: int) -> list[tuple[int, int, np.ndarray]]:
        """Deliver the messages due at or before ``tick``.

        Args:
            tick: Current tick (non-decreasing across calls).

        Returns:
            ``[(sender_id, sent_tick, payload), ...]`` oldest first, ``payload`` a ``(L,)``
            float32 array; empty if nothing is due. :meth:`deliver` adds each payload's format.
        """
        return [d[:3] for d in self.deliver(tick)]

    def deliver(self, tick: int) -> list[Delivery]:
        """:meth:`receive` with each message's payload format: :class:`Delivery` tuples
        ``(sender, tick, payload, format)``, oldest first."""
        self.advance(tick)
        q = self._pending
        if not q or q[0][0] > tick:
            return []
        out = []
        hb = self.config.header_bytes
        while q and q[0][0] <= tick:
            _, n, data = q.popleft()
            if HAVE_JIT:
                ok, sender, sent, payload = decode_kernel(np.frombuffer(data, np.uint8), hb)
                # where a check fails, the codec raises naming the problem
                out.append(Delivery(sender, sent, payload, data[3] >> FORMAT_SHIFT) if ok
                           else Delivery(*decode_frame(data, hb)))
            else:
                out.append(Delivery(*decode_frame(data, hb)))
            self._bytes_delivered += n
            self._n_delivered += 1
        self._last_delivered = out[-1][:3]
        return out

    def receive_latest(self, tick: int) -> tuple[int, int, np.ndarray] | None:
        """Like :meth:`receive` but return only the newest message delivered now (or ``None``).

        Older messages due at the same time are consumed and discarded (still counted as
        delivered).
        """
        out = self.receive(tick)
        return out[-1] if out else None

    @property
    def last_delivered(self) -> tuple[int, int, np.ndarray] | None:
        """The most recent message ever delivered since reset (for sample-and-hold), or ``None``."""
        return self._last_delivered

    @property
    def pending(self) -> int:
        """Messages in flight (transmitted, not lost, not yet delivered)."""
        return len(self._pending)

    # ---------------------------------------------------------------------------------- stats
    @property
    def bytes_sent_total(self) -> int:
        """``stats()["bytes_sent_total"]`` without building the dict."""
        return self._bytes_sent

    @property
    def peak_bps(self) -> float:
        """``stats()["peak_bps"]`` without building the dict."""
        return self._peak / self._window_s

    @property
    def messages_lost(self) -> int:
        """``stats()["messages_lost"]`` without building the dict."""
        return self._n_lost

    @property
    def messages_dropped_bandwidth(self) -> int:
        """``stats()["messages_dropped_bandwidth"]`` without building the dict."""
        return self._n_dropped

    def stats(self) -> dict[str, float | int]:
        """Counters since :meth:`reset` (all numbers; see the class docstring for definitions).

        Returns:
            ``bytes_sent_total`` (bytes on air, lost included, cap drops excluded),
            ``messages_sent`` (transmitted), ``messages_lost``, ``messages_dropped_bandwidth``,
            ``bytes_dropped_bandwidth``, ``messages_delivered``, ``bytes_delivered_total``,
            ``messages_pending``, ``bps`` (bytes/s over ticks 0..now inclusive), ``peak_bps``
            (max bytes in a one-second window of ``W`` ticks, per second), ``last_message_bytes``
            (return value of the latest :meth:`send`), ``ticks_elapsed`` (``now + 1``) and
            ``seconds_elapsed``.
        """
        ticks = self._now + 1
        secs = ticks * self.config.dt
        return {
            "bytes_sent_total": self._bytes_sent,
            "messages_sent": self._n_sent,
            "messages_lost": self.messages_lost,
            "messages_dropped_bandwidth": self.messages_dropped_bandwidth,
            "bytes_dropped_bandwidth": self._bytes_dropped,
            "messages_delivered": self._n_delivered,
            "bytes_delivered_total": self._bytes_delivered,
            "messages_pending": len(self._pending),
            "bps": self._bytes_sent / secs if ticks > 0 else 0.0,
            "peak_bps": self.peak_bps,
            "last_message_bytes": self._last_bytes,
            "ticks_elapsed": ticks,
            "seconds_elapsed": secs,
        }
