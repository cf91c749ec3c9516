"""AURORA's prompts, built only from what the car has at run time.

A prompt is the visual placeholders (one ``<det>`` per fused detection token, one ``<map>`` per
fused map token), the run-time context, the question and ``Answer:``; a planning prompt ends
with ``<wp>``. The context holds the ego's speed, its navigation command and the roadside unit's
pose relative to the ego as its message gives it (``E_{r->e}``; "no message" when none arrived).
It never holds ground-truth objects: :func:`context_from_record` and :func:`prompt_from_record`
read only :data:`RUNTIME_KEYS` of a recorded frame. Chat-V2XBench's export
(``collectors/chat/export.py``) writes this same text as each item's ``context`` (the hint-free
form); the ground-truth object hints that auto-labelled the answers are its separate ``hints``
annotation, never part of a prompt.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import torch
from v2xbench.collectors.chat.templates import COMMAND as COMMAND_PHRASES
from v2xbench.envs.v2x_intersection.town.model import COMMAND_NAMES

from .cqaf import rsu_to_ego
from .tokenizer import DET, MAP, WP

#: The only keys of a recorded frame (``collectors/dataset/record.py``) a prompt reads.
RUNTIME_KEYS = ("ego_speed", "command", ("calib", "T_world_ego"), ("calib", "T_world_rsu"),
                ("calib", "rsu_unit"))
PLAN_QUESTION = "Plan the ego's waypoints for the next three seconds."
NO_MESSAGE = "Roadside unit: no message received."
#: The speed's text in a planning prompt whose speed was dropped in training (speed dropout,
#: :class:`~.pairs.AuroraPairs`); never produced at run time.
UNKNOWN_SPEED = "unknown"


def _array(x) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    return np.asarray(x, np.float64)


def command_phrase(command: int | str) -> str:
    """The words of a navigation command (code in ``COMMAND_NAMES`` or its name)."""
    if isinstance(command, str):
        name = command
    else:
        code = int(command)
        if not 0 <= code < len(COMMAND_NAMES):
            raise ValueError(f"prompt: navigation command {code} outside [0, "
                             f"{len(COMMAND_NAMES)})")
        name = COMMAND_NAMES[code]
    if name not in COMMAND_PHRASES:
        raise ValueError(f"prompt: unknown navigation command {name!r}; known: {COMMAND_NAMES}")
    return COMMAND_PHRASES[name]


def runtime_context(speed: float | None, command: int | str, e_rsu_to_ego=None) -> str:
    """Context lines: speed (m/s; ``None``: "unknown", the speed dropout of training),
    navigation command, the roadside unit's relative pose from its message (``E_{r->e}``
    ``(4, 4)``; ``None``: no message)."""
    if speed is None:
        said = UNKNOWN_SPEED
    else:
        speed = float(speed)
        if not math.isfinite(speed):
            raise ValueError(f"prompt: ego speed {speed!r} is not a finite number")
        said = f"{speed:.1f} m/s"
    lines = [f"Ego speed: {said}; navigation command: {command_phrase(command)}."]
    if e_rsu_to_ego is None:
        lines.append(NO_MESSAGE)
    else:
        e = _array(e_rsu_to_ego)
        if e.shape != (4, 4):
            raise ValueError(f"prompt: the roadside pose must be (4, 4), got {e.shape}")
        heading = math.degrees(math.atan2(e[1, 0], e[0, 0]))
        lines.append(f"Roadside unit relative to the ego: position ({e[0, 3]:.1f}, "
                     f"{e[1, 3]:.1f}) m, heading {heading:.0f} deg.")
    return "\n".join(lines)


def prompt_text(context: str, question: str, *, num_det: int, num_map: int,
                waypoint: bool = False) -> str:
    """The prompt of a run-time ``context`` (:func:`runtime_context`'s text, e.g. a Chat-V2XBench
    item's hint-free ``context``) and a question; ``num_det`` / ``num_map`` placeholders (0: none,
    the text-only prompt of stage 0); ``waypoint``: end with ``<wp>``."""
    if not isinstance(question, str) or not question.strip():
        raise ValueError("prompt: the question is empty")
    if not isinstance(context, str) or not context.strip():
        raise ValueError("prompt: the context is empty")
    for name, n in (("num_det", num_det), ("num_map", num_map)):
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise ValueError(f"prompt: {name}={n!r} must be an int >= 0")
    visual = DET * num_det + MAP * num_map
    text = f"{visual}\n{context.strip()}\nQuestion: {question.strip()}\nAnswer:"
    return text + f" {WP}" if waypoint else text


def build_prompt(speed: float | None, command: int | str, e_rsu_to_ego, question: str, *,
                 num_det: int, num_map: int, waypoint: bool = False) -> str:
    """The model's prompt (module docstring); ``waypoint``: end with ``<wp>``."""
    return prompt_text(runtime_context(speed, command, e_rsu_to_ego), question,
                       num_det=int(num_det), num_map=int(num_map), waypoint=waypoint)


def _get(record: Mapping, key):
    try:
        if isinstance(key, tuple):
            v = record
            for k in key:
                v = v[k]
            return v
        return record[key]
    except (KeyError, TypeError):
        name = "/".join(key) if isinstance(key, tuple) else key
        raise ValueError(f"prompt: the frame has no {name!r}") from None


def context_from_record(record: Mapping, rsu_pose="record") -> str:
    """:func:`runtime_context` of a recorded frame (nested dict or TensorDict of the data set),
    reading only :data:`RUNTIME_KEYS`.

    ``rsu_pose``: ``"record"`` rebuilds the pose the frame's active roadside unit sends
    (:func:`~.cqaf.rsu_to_ego` of the calibration; no message when no unit is active), ``None``
    says no message arrived (e.g. lost, or the No Fusion model), a ``(4, 4)`` matrix is the
    ``E_{r->e}`` of the received message.
    """
    if isinstance(rsu_pose, str):
        if rsu_pose != "record":
            raise ValueError(f"prompt: rsu_pose={rsu_pose!r}; use 'record', None or a (4, 4) "
                             "matrix")
        rsu_pose = None
        if int(_array(_get(record, ("calib", "rsu_unit")))) >= 0:
            rsu_pose = rsu_to_ego(_array(_get(record, ("calib", "T_world_ego"))),
                                  _array(_get(record, ("calib", "T_world_rsu"))))
    return runtime_context(float(_array(_get(record, "ego_speed"))),
                           int(_array(_get(record, "command"))), rsu_pose)


def prompt_from_record(record: Mapping, question: str = PLAN_QUESTION, *, num_det: int,
                       num_map: int, waypoint: bool = False, rsu_pose="record") -> str:
    """:func:`build_prompt` of a recorded frame, reading only :data:`RUNTIME_KEYS`
    (``rsu_pose``: as :func:`context_from_record`)."""
    return prompt_text(context_from_record(record, rsu_pose), question, num_det=int(num_det),
                       num_map=int(num_map), waypoint=waypoint)


def template_texts() -> list[str]:
    """The fixed phrases of the run-time prompt (for training the tokenizer and stage 0)."""
    out = [NO_MESSAGE, PLAN_QUESTION, "Question:", "Answer:",
           "Roadside unit relative to the ego: position (12.3, -4.5) m, heading 90 deg."]
    out += [runtime_context(v, c) for v in (0.0, 5.5, 12.5, None)
            for c in range(len(COMMAND_NAMES))]
    return out


__all__ = ["NO_MESSAGE", "PLAN_QUESTION", "RUNTIME_KEYS", "UNKNOWN_SPEED", "build_prompt",
           "command_phrase",
           "context_from_record", "prompt_from_record", "prompt_text", "runtime_context",
           "template_texts"]
