"""How rough the flight is, for an accelerometer density that follows it
(``NavNoise.accel_rough``).

A fixed velocity random walk does not fit a turbulent flight and a calm one: fitted to a
windy ArduCopter SITL flight it leaves calm flights' velocity under-confident, and fitted
to the calm ones it makes the windy flight over-confident (docs/navigation.md, "An
accelerometer density that follows the flight"). What separates them is the specific
force's change between consecutive :data:`ROUGH_BLOCK_S` means, RMS over the three body
axes: in the middle of each flight, 0.27 m/s^2 on the windy flight and 0.08-0.09 on the
calm ones (over whole runs, ground included, 0.21 and 0.04). The blocks' length sets the
scale, not the IMU's rate, so the figure is the same at 50 Hz and 200 Hz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..models.navigation import ImuTransition

__all__ = ["ROUGH_BLOCK_S", "ROUGH_TAU_S", "RoughDensity"]

#: The specific force's change is taken between consecutive means over this long (s): the
#: default filter step (25 Hz), so that a 25 Hz step's mean force is one block.
ROUGH_BLOCK_S = 0.04
#: ... its square averaged over an exponential window of this long (s).
ROUGH_TAU_S = 5.0
#: a block this many times :data:`ROUGH_BLOCK_S` or longer (an IMU gap) is not compared,
#: so a stream whose steps are that long (an IMU slower than about 8 Hz) has no roughness
#: and keeps its base density
_MAX_BLOCK = 3.0
#: the density is rounded to steps of this ratio, so the step's model changes only when
#: the density has moved by that much
_LEVEL = math.log(1.05)

Array = np.ndarray


@dataclass
class RoughDensity:
    """The running roughness and the step models it gives (mutable: a stream's snapshots
    copy it). Fields: the open block's force integral (m/s, FRD, x / y / z) and length
    (s); the last block's mean (m/s^2); the exponentially weighted sum of squared changes
    and its weight; the last model made (base model, level, model); the densities used and
    the roughness, weighted by time (their sums, the time, the least and most density)."""

    acc: tuple[float, float, float] | None = None
    span: float = 0.0
    last: tuple[float, float, float] | None = None
    s: float = 0.0
    w: float = 0.0
    made: tuple[ImuTransition, int, ImuTransition] | None = None
    q_sum: float = 0.0
    r_sum: float = 0.0
    q_time: float = 0.0
    q_min: float = math.inf
    q_max: float = 0.0

    @property
    def rms(self) -> float:
        """The specific force's RMS change between consecutive blocks, m/s^2 (0 before
        two blocks)."""
        return math.sqrt(self.s / self.w) if self.w > 0 else 0.0

    def add(self, a: Array, dt: float) -> None:
        """One step's mean specific force ``a`` (m/s^2, FRD) over ``dt`` s (in floats: a
        step's worth of numpy calls on 3-vectors cost more than the arithmetic)."""
        x, y, z = a.tolist()
        if not (dt > 0 and math.isfinite(x + y + z)):
            return
        c = self.acc
        self.acc = (x * dt, y * dt, z * dt) if c is None else (
            c[0] + x * dt, c[1] + y * dt, c[2] + z * dt)
        self.span += dt
        if self.span + 0.5 * dt < ROUGH_BLOCK_S:
            return
        k = 1.0 / self.span
        mean = (self.acc[0] * k, self.acc[1] * k, self.acc[2] * k)
        whole = self.span < _MAX_BLOCK * ROUGH_BLOCK_S
        last = self.last
        if last is not None and whole:
            decay = math.exp(-self.span / ROUGH_TAU_S)
            d2 = ((mean[0] - last[0]) ** 2 + (mean[1] - last[1]) ** 2
                  + (mean[2] - last[2]) ** 2) / 3.0
            self.s = self.s * decay + d2
            self.w = self.w * decay + 1.0
        self.last = mean if whole else None
        self.acc, self.span = None, 0.0

    def model(self, base: ImuTransition, a: Array, dt: float) -> ImuTransition:
        """The step's transition after its mean specific force ``a`` (m/s^2) over ``dt``
        s: ``base`` with the density ``sqrt(accel_noise^2 + (accel_rough * rms)^2)``
        (m/s^2/sqrt(Hz)) rounded to 5 % steps; ``base`` itself when its noise has no
        ``accel_rough``."""
        n = base.noise
        if n.accel_rough <= 0:
            return base
        self.add(a, dt)
        # (at least 1e-9: a base of 0 on a still start has no density to take a log of)
        q = max(math.hypot(n.accel_noise, n.accel_rough * self.rms), 1e-9)
        level = round(math.log(q) / _LEVEL)
        if self.made is None or self.made[0] is not base or self.made[1] != level:
            made = base.with_noise(n.with_(accel_noise=math.exp(level * _LEVEL)))
            self.made = (base, level, made)
        q = self.made[2].noise.accel_noise  # the density the step takes (rounded)
        self.q_sum += q * dt
        self.r_sum += self.rms * dt
        self.q_time += dt
        self.q_min, self.q_max = min(self.q_min, q), max(self.q_max, q)
        return self.made[2]

    def summary(self) -> dict[str, Any] | None:
        """The densities used (m/s^2/sqrt(Hz)): least, time-weighted mean and most, and
        the roughness's time-weighted mean (m/s^2); None when none was."""
        if self.q_time <= 0:
            return None
        return {"min": self.q_min, "mean": self.q_sum / self.q_time, "max": self.q_max,
                "roughness_ms2": self.r_sum / self.q_time}
