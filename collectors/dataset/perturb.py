"""Control perturbations that teach recovery (DAgger-style noise injection, as in PDM-Lite data).

Now and then, while the expert drives freely, the executed control gets a short burst of
steering and throttle noise; the recorded label stays the expert's control for the state it is
in, so the data set holds drifts away from the lane followed by the expert's corrections. A burst
starts only on a free road (expert reason ``free``) above ``min_speed`` and ends early when the
expert's binding constraint changes, so the noise never fights a stop for a light or an object.
Bursts are drawn from their own generator (seeded per episode), not the world's, so the world's
random stream is unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PerturbConfig:
    """Noise bursts.

    Attributes:
        rate_per_s: probability per second that a burst starts (when allowed).
        duration_s: ``(min, max)`` burst length (s).
        steer: ``(min, max)`` magnitude of the steering offset (sign drawn at random).
        throttle: ``(min, max)`` throttle offset (added when the expert is not braking).
        min_speed: no burst below this speed (m/s).
    """

    rate_per_s: float = 0.08
    duration_s: tuple[float, float] = (0.5, 1.2)
    steer: tuple[float, float] = (0.08, 0.25)
    throttle: tuple[float, float] = (0.0, 0.25)
    min_speed: float = 3.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.rate_per_s <= 10.0:
            raise ValueError(f"PerturbConfig: rate_per_s={self.rate_per_s!r} must be in [0, 10]")
        for name in ("duration_s", "steer", "throttle"):
            lo, hi = getattr(self, name)
            if not 0.0 <= lo <= hi:
                raise ValueError(f"PerturbConfig: {name}={(lo, hi)!r} must be 0 <= min <= max")


class Perturber:
    """Applies :class:`PerturbConfig` bursts to the expert's controls of one episode.

    Args:
        config: the bursts (``None``: never perturb).
        seed: episode seed (the burst generator is ``default_rng([seed, 0x5EED])``).
        dt: tick (s).
    """

    def __init__(self, config: PerturbConfig | None, seed: int, dt: float = 0.1) -> None:
        self.config, self.dt = config, dt
        self.rng = np.random.default_rng([int(seed), 0x5EED])
        self.left = 0  # ticks left in the running burst
        self.offset = np.zeros(3)
        self.events: list[tuple[int, int, float, float]] = []  # (tick, ticks, steer, throttle)

    def apply(self, tick: int, control: np.ndarray, speed: float, reason: str) -> tuple[np.ndarray, bool]:
        """``(executed control, perturbed)`` for the expert's ``control`` at ``tick``."""
        c = self.config
        control = np.asarray(control, np.float64).reshape(3)
        if c is None:
            return control.astype(np.float32), False
        if self.left > 0 and reason != "free":
            self.left = 0
        if self.left == 0 and reason == "free" and speed >= c.min_speed:
            if self.rng.random() < c.rate_per_s * self.dt:
                ticks = max(1, int(round(self.rng.uniform(*c.duration_s) / self.dt)))
                steer = float(self.rng.choice([-1.0, 1.0]) * self.rng.uniform(*c.steer))
                thr = float(self.rng.uniform(*c.throttle))
                self.left, self.offset = ticks, np.array([thr, steer, 0.0])
                self.events.append((int(tick), ticks, steer, thr))
        if self.left == 0:
            return control.astype(np.float32), False
        self.left -= 1
        out = control + self.offset * np.array([control[2] <= 0.0, 1.0, 0.0])
        out = np.clip(out, [0.0, -1.0, 0.0], [1.0, 1.0, 1.0])
        return out.astype(np.float32), True


__all__ = ["PerturbConfig", "Perturber"]
