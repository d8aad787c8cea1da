"""Gradient hardware presets and the dB/dt (peripheral nerve stimulation) limit.

Presets (amplitude, slew, sequence timing).  Where a number is ours, it says so.

* ``paper``: 80 mT/m (Section III-C), the clinical 100 T/m/s slew we default
  to (docs/control.md), continuous imaging at the control rate, no latency:
  today's loop, bit for bit.
* ``clinical_3t``: a current clinical 3 T whole-body gradient system,
  45 mT/m at 200 T/m/s (Siemens MAGNETOM Skyra datasheet).  Tracking sequence: a 20 ms tracking window (ours: "a few tens
  of ms", Tamaz et al. 2008 image and propel alternately with such windows),
  2 ms switching dead time (ours: 45 mT/m at 200 T/m/s ramps in 0.23 ms, plus
  eddy-current settling), 30 ms propulsion window (ours: 1:1.5 imaging to
  propulsion), 20 ms reconstruction and localisation latency (ours).
* ``propulsion_insert``: a dedicated propulsion gradient insert of the
  Maxwell-pair class, 400 mT/m (as reported for the propulsion gradient coils
  of Mathieu and Martel, Magn. Reson. Med. 2010), 100 T/m/s (ours), with
  the same tracking timing and a longer 60 ms propulsion window (ours).

dB/dt.  A gradient ramp induces ``dB/dt = S r`` at distance ``r`` from the
isocentre.  IEC 60601-2-33 bounds it by the mean peripheral-nerve-stimulation
threshold, in normal operating mode
``dB/dt <= 0.8 rb (1 + 0.36 / t_eff)`` with the rheobase ``rb = 20 T/s`` and
the effective stimulus duration ``t_eff`` in ms; :func:`iec_normal_mode_dbdt`
computes it, and :func:`dbdt_slew_limit` turns it into a slew limit.
"""

from __future__ import annotations

import dataclasses

from vesselbot_ros.config import ConfigError, check_positive
from vesselbot_ros.scanner.sequence import SequenceParams

__all__ = ["HardwarePreset", "PRESETS", "iec_normal_mode_dbdt", "dbdt_slew_limit"]

RHEOBASE_T_PER_S = 20.0  # IEC 60601-2-33 rb


@dataclasses.dataclass(frozen=True)
class HardwarePreset:
    """One scanner's gradient hardware and navigation sequence."""

    name: str
    saturation_T_per_m: float
    slew_T_per_m_per_s: float
    sequence: SequenceParams
    source: str


PRESETS: dict[str, HardwarePreset] = {
    "paper": HardwarePreset("paper", 0.08, 100.0, SequenceParams(mode="continuous", latency_s=0.0),
                            "Section III-C: 80 mT/m; slew: clinical 100 T/m/s (docs/control.md)"),
    "clinical_3t": HardwarePreset(
        "clinical_3t", 0.045, 200.0,
        SequenceParams(mode="multiplexed", tracking_window_s=0.02, dead_time_s=0.002, propulsion_window_s=0.03,
                       latency_s=0.02),
        "45 mT/m, 200 T/m/s: Siemens MAGNETOM Skyra datasheet; windows and latency: ours"),
    "propulsion_insert": HardwarePreset(
        "propulsion_insert", 0.4, 100.0,
        SequenceParams(mode="multiplexed", tracking_window_s=0.02, dead_time_s=0.001, propulsion_window_s=0.06,
                       latency_s=0.02),
        "400 mT/m: Mathieu and Martel, MRM 2010 (propulsion gradient insert); slew, windows, latency: ours"),
}


def iec_normal_mode_dbdt(t_eff_ms: float) -> float:
    """IEC 60601-2-33 normal-mode dB/dt limit (T/s) for an effective stimulus duration ``t_eff_ms`` (ms)."""
    check_positive("t_eff_ms", t_eff_ms)
    return 0.8 * RHEOBASE_T_PER_S * (1.0 + 0.36 / t_eff_ms)


def dbdt_slew_limit(dbdt_T_per_s: float, radius_m: float) -> float:
    """Slew rate (T/m/s) that keeps ``dB/dt = S r`` below ``dbdt_T_per_s`` within ``radius_m`` of the isocentre."""
    check_positive("dbdt_T_per_s", dbdt_T_per_s)
    check_positive("radius_m", radius_m)
    if radius_m > 2.0:
        raise ConfigError(f"radius_m must be <= 2 m (inside the bore), got {radius_m!r}")
    return dbdt_T_per_s / radius_m
