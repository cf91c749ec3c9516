"""The baselines' payloads: a raw payload's float16 rounding (:func:`to_payload`) and its header
check (:func:`read_header`). Header: ``MAGIC``, ``VERSION`` (each method's own), then the
method's sizes."""

from __future__ import annotations

import numpy as np
from v2xbench.envs.v2x_intersection.v2x.wire import PAYLOAD_LIMIT


def to_payload(flat: np.ndarray) -> np.ndarray:
    """``flat`` as a raw payload: float32 values float16-representable (clipped to
    ``+-PAYLOAD_LIMIT``, rounded to float16 as the channel sends them)."""
    return np.clip(flat, -PAYLOAD_LIMIT, PAYLOAD_LIMIT).astype(np.float16).astype(np.float32)


def read_header(payload: np.ndarray, magic: float, version: float, header_floats: int,
                title: str) -> tuple[np.ndarray, tuple[int, ...]]:
    """``(payload as flat float32, the header's sizes as ints)`` of a method's payload.

    Raises:
        ValueError: shorter than the header, or not this method's ``magic`` and ``version``.
    """
    x = np.asarray(payload, np.float32).reshape(-1)
    if x.shape[0] < header_floats or x[0] != magic or x[1] != version:
        raise ValueError(f"{title} deserialize_message: not a {title} roadside message (header "
                         f"{x[:2].tolist()}, expected [{magic}, {version}])")
    return x, tuple(int(v) for v in x[2:header_floats])


__all__ = ["read_header", "to_payload"]
