"""An observer with a very wrong gain, for the tests of the divergence rule (``sim/metrics.py``).

``observer.kind: vesselbot_divergent_plugin:WrongGainObserver`` (with ``test/plugins``
on ``PYTHONPATH``): it reports each frame's position times ``gain`` (1000 by
default, a units bug of the mm-for-m kind), so its estimate lies metres from the
vessel as soon as the first frame arrives, while the true bead stays inside.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.estimate import Estimate


@dataclasses.dataclass(frozen=True)
class WrongGainParams:
    """The observer section: ``gain`` multiplies every measured position (-)."""

    kind: str = "vesselbot_divergent_plugin:WrongGainObserver"
    gain: float = 1000.0

    def __post_init__(self) -> None:
        if not math.isfinite(self.gain):
            raise ConfigError(f"gain must be finite, got {self.gain!r}")


class WrongGainObserver:
    """Estimate = ``gain`` times the last frame's position; zero velocity."""

    ROLE = "observer"
    Params = WrongGainParams

    def __init__(self, params: WrongGainParams, context: Any) -> None:
        self.gain = float(params.gain)
        self._x = np.asarray(context.scenario.initial.p0_m, dtype=np.float64).copy()
        self._t_meas = -math.inf

    def update(self, t_s: float, measurement: Any, g_prev: Any) -> Estimate:
        used = measurement is not None
        if used:
            self._x = self.gain * np.asarray(measurement.p, dtype=np.float64)
            self._t_meas = float(measurement.t_acq_s)
        return Estimate(float(t_s), self._x.copy(), np.zeros_like(self._x), float(t_s) - self._t_meas,
                        np.zeros_like(self._x), used, False)
