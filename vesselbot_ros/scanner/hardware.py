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
* ``clinical_3t_mfde``: the same gradient system with the navigation
  sequence of Zhai et al., Engineering 2026 (multi-frequency dual-echo
  imaging, TR 30 ms, up to 77 % of it driving).  Windows fall on whole
  control ticks (1 ms) and the tracking window is an even number of them, so
  77 % of 30 ms (23.1 ms) cannot be split exactly; ours: the nearest split
  below it, 22 ms of propulsion (73 %), a 6 ms tracking window, two 1 ms dead
  times, and the 20 ms latency.
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

As a coil limit (:class:`DbdtLimit`, the scenario's ``dbdt:`` section, off by
default).  The two gradient axes share one field, ``B_z = G_x x + G_z z``, so
within radius ``r`` of the isocentre ``dB/dt <= r |dG/dt|`` (Euclidean norm).
The coil limits each axis's step to ``S dt``, so the norm can reach
``sqrt(2) S``: the per-axis slew that keeps ``dB/dt`` within the IEC limit
is ``S sqrt(2) r <= 0.8 rb (1 + 0.36 / t_eff)``.  The effective stimulus
duration is the full-scale ramp at that slew, ``t_eff = G_sat / S`` (in ms,
``1000 G_sat / S``), so the bound is a fixed point with the closed form
``S = 0.8 rb / (sqrt(2) r - 0.8 rb 0.36e-3 / G_sat)``
(:func:`dbdt_axis_slew_limit`; no bound when the denominator is <= 0: the
allowance then grows faster with a shorter ramp than dB/dt does).  The coil
slews at the smaller of its hardware rate and that bound
(:func:`effective_coil_limits`).  In a 3-D vessel tree the three axes share the field,
``B_z = G_x x + G_y y + G_z z``, and the norm can reach ``sqrt(3) S``: the same rule with ``sqrt(3)``
(``axes=3``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Literal

from vesselbot_ros.config import ConfigError, check_choice, check_positive, flatten
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.scanner.actuator_limits import CoilLimits
from vesselbot_ros.scanner.input_mapping import input_matrix
from vesselbot_ros.scanner.sequence import SequenceParams, duty_cycle

__all__ = ["weight_accel", "hover_shortfall",
           "HardwarePreset", "PRESETS", "preset_changes", "iec_normal_mode_dbdt", "dbdt_slew_limit", "DbdtLimit", "dbdt_axis_slew_limit",
           "effective_coil_limits", "dbdt_at"]

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
    "clinical_3t_mfde": HardwarePreset(
        "clinical_3t_mfde", 0.045, 200.0,
        SequenceParams(mode="multiplexed", tracking_window_s=0.006, dead_time_s=0.001, propulsion_window_s=0.022,
                       latency_s=0.02),
        "45 mT/m, 200 T/m/s as clinical_3t; sequence: Zhai et al., Engineering 2026 (MFDE: TR 30 ms, driving "
        "duty up to 77 %); ours: the split of the TR on whole 1 ms ticks nearest below 77 % (22 ms of "
        "propulsion, 73 %), the 6 ms tracking window, the 1 ms dead times and the latency"),
    "propulsion_insert": HardwarePreset(
        "propulsion_insert", 0.4, 100.0,
        SequenceParams(mode="multiplexed", tracking_window_s=0.02, dead_time_s=0.001, propulsion_window_s=0.06,
                       latency_s=0.02),
        "400 mT/m: Mathieu and Martel, MRM 2010 (propulsion gradient insert); slew, windows, latency: ours"),
}


def preset_changes(name: str, **sequence: Any) -> dict[str, Any]:
    """A hardware preset as dotted-key changes to a scenario: its coil, its whole sequence (``sequence`` keys
    replace the preset's), no imager latency of its own (the sequence's latency is the scanner's).

    The one meaning of ``--hardware PRESET`` (``simulate``, ``run``, ``plan``, ``plan-design``: through
    :func:`vesselbot_ros.sim.scenario.load_scenario`'s ``hardware``) and of a scanner study's hardware; ``--set``
    applies after it.

    Raises:
        ConfigError: ``name`` is not a preset (the message lists the known ones).
    """
    if name not in PRESETS:
        raise ConfigError(f"--hardware: unknown scanner preset {name!r}; known presets: {', '.join(sorted(PRESETS))}")
    hw = PRESETS[name]
    seq = {f.name: getattr(hw.sequence, f.name) for f in dataclasses.fields(SequenceParams)}
    seq.update(sequence)
    return {**flatten(seq, "sequence."),
            "coil.saturation_T_per_m": hw.saturation_T_per_m, "coil.slew_rate": "custom",
            "coil.custom_slew_rate_T_per_m_per_s": hw.slew_T_per_m_per_s,
            "imager.latency_s": 0.0}


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


@dataclasses.dataclass(frozen=True)
class DbdtLimit:
    """The dB/dt (peripheral nerve stimulation) limit of the coil (module docstring).

    Attributes:
        mode: ``off`` (the paper: slew limit only) or ``iec_normal_mode``
            (IEC 60601-2-33 normal operating mode, applied as a slew limit).
        radius_m: Distance from the isocentre within which dB/dt is bounded
            (m), in ``(0, 2]``.
    """

    mode: Literal["off", "iec_normal_mode"] = "off"
    radius_m: float = 0.2

    def __post_init__(self) -> None:
        check_choice("mode", self.mode, ("off", "iec_normal_mode"))
        check_positive("radius_m", self.radius_m)
        if self.radius_m > 2.0:
            raise ConfigError(f"radius_m must be <= 2 m (inside the bore), got {self.radius_m!r}")


def dbdt_axis_slew_limit(saturation_T_per_m: float, radius_m: float, axes: int = 2) -> float:
    """Per-axis slew (T/m/s) that keeps dB/dt within the IEC normal-mode limit inside ``radius_m`` when ``axes`` gradient
    axes slew at once (2: the paper's plane; 3: a 3-D tree); inf if none binds."""
    check_positive("saturation_T_per_m", saturation_T_per_m)
    check_positive("radius_m", radius_m)
    if axes not in (2, 3):
        raise ConfigError(f"axes must be 2 or 3, got {axes!r}")
    a = 0.8 * RHEOBASE_T_PER_S
    den = math.sqrt(float(axes)) * radius_m - a * 0.36e-3 / saturation_T_per_m
    return a / den if den > 0.0 else math.inf


def dbdt_at(limit: DbdtLimit, saturation_T_per_m: float, slew_T_per_m_per_s: float) -> float:
    """The IEC normal-mode dB/dt limit (T/s) for a full-scale ramp at the per-axis slew ``slew_T_per_m_per_s``."""
    check_positive("slew_T_per_m_per_s", slew_T_per_m_per_s)
    return iec_normal_mode_dbdt(1e3 * saturation_T_per_m / slew_T_per_m_per_s)


def effective_coil_limits(coil: CoilLimits, limit: DbdtLimit, axes: int = 2) -> CoilLimits:
    """``coil`` with its slew lowered to the dB/dt bound of ``axes`` axes when that binds (``coil`` itself when
    ``mode: off``)."""
    if limit.mode == "off":
        return coil
    s_db = dbdt_axis_slew_limit(coil.saturation_T_per_m, limit.radius_m, axes)
    if s_db >= coil.slew_rate_T_per_m_per_s:
        return coil
    return dataclasses.replace(coil, slew_rate="custom", custom_slew_rate_T_per_m_per_s=s_db)


def weight_accel(physics: PhysicsParams) -> float:
    """The acceleration the apparent weight gives the bead (m/s^2, downward): ``V (rho - rho_f) g / m``."""
    r = physics.robot
    volume = 4.0 / 3.0 * math.pi * r.radius_m ** 3
    return float(volume * (r.density_kg_per_m3 - physics.blood.density_kg_per_m3) * physics.vessel.gravity_m_per_s2
                 / r.mass_kg)


def hover_shortfall(physics: PhysicsParams, saturation_T_per_m: float,
                    sequence: SequenceParams) -> tuple[float, float] | None:
    """``(a_avail, a_weight)`` when the saturated coil, duty-averaged, cannot hold the bead against its apparent
    weight, else None.

    ``a_avail`` is the vertical axis's acceleration at saturation times the sequence's duty cycle (as
    :func:`vesselbot_ros.analysis.plan.available_accel`), ``a_weight`` :func:`weight_accel`.  A bound for every
    loop: no controller hovers such a bead, so only a path resting on the lower wall can be flown
    (``vesselbot plan``).  The planar model's axes (x, z).
    """
    a_avail = duty_cycle(sequence) * abs(float(input_matrix(physics)[1, 1])) * saturation_T_per_m
    a_weight = weight_accel(physics)
    return (a_avail, a_weight) if a_avail < a_weight else None
