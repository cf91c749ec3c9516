"""The baselines' configuration dataclasses share their construction (:class:`ScaledConfig`: a
scale table, ``to_dict`` / ``from_dict``) and their validation helpers (each raises
``ValueError`` naming the class, the field, its value and the bound)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar

from v2xbench.agents.aurora.config import StageHParams, check_branch
from v2xbench.envs.v2x_intersection.sim.config import FIELD_RULES

from .plan_frame import check_switches

#: Fields a run written before they existed (2026-11-28) had in effect: its planner was told the
#: ego's speed, in the ego frame (the defaults since: the route frame, never told the speed);
#: UniV2X / UniMM-V2X trained on the same tick's roadside message (since the second stop: one
#: tick older), V2X-ViT / CoDriving on ages from 0 (since the third stop: from 1 tick).
LEGACY_FIELDS: dict[str, Any] = {"plan_ego_speed": True, "plan_frame": "ego",
                                 "msg_latency_ticks": 0}


class ScaledConfig:
    """Mixin of a frozen configuration dataclass with named scales.

    The class sets :attr:`TITLE` (the method's name in messages) and, after its module's scale
    table is built, :attr:`SCALE_FIELDS` (scale name -> field values over the defaults).
    """

    TITLE: ClassVar[str] = ""
    SCALES: ClassVar[tuple[str, ...]] = ("tiny", "default", "paper")
    SCALE_FIELDS: ClassVar[dict[str, dict[str, Any]]] = {}

    @classmethod
    def for_scale(cls, name: str, **overrides: Any):
        """The named scale with field ``overrides`` (unknown scale or field: ``ValueError``)."""
        if name not in cls.SCALE_FIELDS:
            raise ValueError(f"unknown {cls.TITLE} scale {name!r}; known scales: "
                             f"{', '.join(cls.SCALES)}")
        unknown = set(overrides) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ValueError(f"{cls.__name__}: unknown fields {sorted(unknown)}")
        return cls(**{**cls.SCALE_FIELDS[name], "scale": name, **overrides})

    def pc_range(self, branch: str) -> tuple[float, ...]:
        """The agent's range ``(xmin, ymin, zmin, xmax, ymax, zmax)`` (``ego_range`` or
        ``rsu_range``)."""
        return self.ego_range if check_branch(branch) == "ego" else self.rsu_range

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form; :meth:`from_dict` reads it back."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]):
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError`` naming them. A dict
        without the planner switches is an older run's: :data:`LEGACY_FIELDS`."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"{cls.__name__}: unknown keys {sorted(unknown)}")
        kw = {**{k: v for k, v in LEGACY_FIELDS.items() if k in names},
              **{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}}
        if isinstance(kw.get("train"), dict):
            kw["train"] = StageHParams.from_dict(kw["train"])
        return cls(**kw)


#: The ``tiny`` scale's training settings (every baseline's).
TINY_TRAIN = StageHParams(batch_size=2, epochs=1, lr=1e-3, warmup_iters=0, num_workers=0)


def grid_ok(g: tuple[int, int]) -> bool:
    """Whether ``g`` is two ints >= 1 (cells along x, y)."""
    return len(g) == 2 and all(isinstance(v, int) and not isinstance(v, bool) and v >= 1
                               for v in g)


def check_ints(cfg: Any, who: str, names: tuple[str, ...], lo: int = 1) -> None:
    """Each field of ``names`` an int (not a bool) ``>= lo``."""
    for name in names:
        v = getattr(cfg, name)
        if not isinstance(v, int) or isinstance(v, bool) or v < lo:
            raise ValueError(f"{who}: {name}={v!r} must be an int >= {lo}")


def check_positive(cfg: Any, who: str, names: tuple[str, ...]) -> None:
    """Each field of ``names`` a finite number ``> 0``."""
    for name in names:
        v = getattr(cfg, name)
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{who}: {name}={v!r} must be a positive number")


def check_ranges(cfg: Any, who: str) -> None:
    """``ego_range`` and ``rsu_range`` each ``(xmin, ymin, zmin, xmax, ymax, zmax)``, min < max."""
    for name in ("ego_range", "rsu_range"):
        r = getattr(cfg, name)
        if len(r) != 6 or not all(r[i] < r[i + 3] for i in range(3)):
            raise ValueError(f"{who}: {name}={r!r} must be (xmin, ymin, zmin, xmax, "
                             "ymax, zmax) with min < max")


def check_planning(cfg: Any, who: str, positive: tuple[str, ...], code_weights: str,
                   lower: str) -> None:
    """The last checks every baseline's config makes: the fields ``positive`` positive numbers,
    the planner switches (:func:`~.plan_frame.check_switches`), ``plan_route_points`` in
    ``[0, 16]``, 10 box code weights (field ``code_weights``), and the
    roadside message within a channel (:func:`check_message_size`; ``lower`` names the fields
    to lower)."""
    check_positive(cfg, who, positive)
    check_switches(cfg, who)
    if isinstance(cfg.plan_route_points, bool) or not 0 <= cfg.plan_route_points <= 16:
        raise ValueError(f"{who}: plan_route_points={cfg.plan_route_points!r} must "
                         "be an int in [0, 16]")
    if len(getattr(cfg, code_weights)) != 10:
        raise ValueError(f"{who}: {code_weights} needs 10 values")
    check_message_size(cfg, who, lower)


def check_message_size(cfg: Any, who: str, lower: str) -> None:
    """The roadside message (``cfg.message_floats()``) within what a channel carries;
    ``lower`` names the fields to lower."""
    limit = FIELD_RULES["max_payload_floats"].hi
    if cfg.message_floats() > limit:
        raise ValueError(f"{who}: the roadside message has {cfg.message_floats()} "
                         f"floats, more than a channel carries (max_payload_floats <= "
                         f"{limit}); lower {lower}")


__all__ = ["LEGACY_FIELDS", "TINY_TRAIN", "ScaledConfig", "check_ints", "check_message_size",
           "check_planning", "check_positive", "check_ranges", "grid_ok"]
