"""The vehicle's sensor spec (its ``SPEC_*`` parameters, :mod:`uavest.link.spec`) as
the start of a navigation run: the noise and GNSS delay that the options leave open.

``uavest demo`` used to hand its estimator the simulator's datasheet itself; now the
simulator states it as parameters and every run takes it from there, so that ``uavest
run`` attached to ``uavest sim`` (or to any vehicle that states them) and the replay of
its tlog start as the demo does (docs/navigation.md, "The vehicle's sensor spec"). Order:
options (and ``--aiding-from``, for the values it gives) over the spec, the spec over the
replay's probe and the IMU source's profile.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..link.spec import PARAM_OF, SPEC_PARAMS, describe, sensor_spec

__all__ = ["GNSS_BIAS_KEYS", "SPEC_PRESCAN_MESSAGES", "SpecStart", "read_log_spec",
           "with_sensor_spec"]

#: A run over a MAVLink log looks this far into it (messages) for the vehicle's sensor spec
#: (a ``uavest sim --params`` log has it first, a live session's tlog within its first
#: seconds, where the run asked for it).
SPEC_PRESCAN_MESSAGES = 5000

#: the GNSS bias states' noise names, which one decision line says together
GNSS_BIAS_KEYS = ("gnss_bias_h", "gnss_bias_v", "gnss_bias_tau")


@dataclass(frozen=True)
class SpecStart:
    """The vehicle's sensor spec for a navigation run: ``taken``, the values the run takes
    (noise name -> value; ``gnss_delay`` s among them), ``stated``, all it states, and
    ``skipped``, its parameters not taken for a bad value (``NAME=value (why)``)."""

    taken: dict[str, float] = field(default_factory=dict)
    stated: dict[str, float] = field(default_factory=dict)
    skipped: list[str] = field(default_factory=list)

    def merged(self, noise: dict[str, float], gnss_delay: float | None
               ) -> tuple[dict[str, float], float | None]:
        """(noise overrides, GNSS delay s) of the run: the options' ``noise`` and
        ``gnss_delay`` (None: open) with the values taken."""
        taken = {k: v for k, v in self.taken.items() if k != "gnss_delay"}
        return {**taken, **noise}, self.taken.get("gnss_delay", gnss_delay)

    @property
    def why(self) -> str | None:
        """Where the values taken came from, for the decision lines (None: none taken)."""
        if not self.taken:
            return None
        return (f"the vehicle's sensor spec ({describe(self.taken)}; --noise KEY=VALUE or "
                "--gnss-delay S to set one)"
                + (f"; skipped: {', '.join(self.skipped)}" if self.skipped else ""))

    def why_of(self, *keys: str) -> str | None:
        """The decision line's why for the noise names ``keys`` if the spec gave any."""
        got = [PARAM_OF[k] for k in keys if k in self.taken]
        return f"the vehicle's sensor spec ({', '.join(got)})" if got else None

    def as_dict(self) -> dict[str, Any] | None:
        """For the result document (None when the vehicle states nothing)."""
        if not self.stated and not self.skipped:
            return None
        return {"taken": self.taken, "stated": self.stated, "skipped": self.skipped}


def read_log_spec(src: Any) -> None:
    """Read the vehicle's sensor spec from the start of the log source ``src`` into its
    parameters before the run (``uavest replay``, the live job over a session's tlog):
    the first :data:`SPEC_PRESCAN_MESSAGES` messages of a MAVLink log; a source without
    a pre-scan (a ULog: its parameters are in its header) is left as it is."""
    if hasattr(src, "prescan_params"):
        src.prescan_params(SPEC_PARAMS, SPEC_PRESCAN_MESSAGES)


def with_sensor_spec(params: dict[str, Any], noise: dict[str, float],
                     gnss_delay: float | None) -> SpecStart:
    """The vehicle's spec from its (or its log's) parameters ``params``, taken where the
    options' noise overrides ``noise`` and GNSS delay ``gnss_delay`` (s, None: open)
    leave a value open."""
    stated, skipped = sensor_spec(params)
    taken = {k: v for k, v in stated.items()
             if k not in noise and not (k == "gnss_delay" and gnss_delay is not None)}
    return SpecStart(taken, stated, skipped)
