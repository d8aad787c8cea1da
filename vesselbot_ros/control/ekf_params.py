"""Settings of the extended Kalman observer (:mod:`vesselbot_ros.control.ekf_observer`)."""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

from vesselbot_ros.config import OMIT_IF, check_choice, check_nonnegative, check_positive

__all__ = ["EkfParams", "CHI2_2DOF_999"]

#: Chi-square quantile, 2 degrees of freedom, 99.9 %: -2 ln(0.001).
CHI2_2DOF_999 = -2.0 * math.log(0.001)


@dataclasses.dataclass(frozen=True)
class EkfParams:
    """Extended Kalman filter settings (see the module docstring).

    Attributes:
        measurement_sigma_m: Standard deviation of a frame per axis (m); the
            imager's ``noise_sigma_m`` is the honest choice.
        accel_noise_m_per_s2_sqrt_s: ``q_a``, density of the white acceleration
            noise standing for unmodelled forces (m/s^2 per sqrt(Hz)).
        flow_scale_noise_per_sqrt_s: ``q_s``, random-walk density of ``s`` (1/sqrt(s)).
        flow_scale0: Prior of ``s`` (-).
        flow_scale_sigma0: Prior standard deviation of ``s`` (-).
        position_sigma0_m: Prior standard deviation of the position (m), used
            after the first frame initialises the position.
        velocity_sigma0_m_per_s: Prior standard deviation of the velocity (m/s).
        gate_chi2: Reject a frame with ``nu^T S^-1 nu`` above this; 0 disables.
        max_consecutive_rejections: After this many rejections in a row the
            filter restarts its track on the next frame (position from the
            frame, prior covariance).
        max_rejection_s: The same once the frames rejected in a row span this
            long (s, from the first one's acquisition to the current frame's);
            0: off.  At a few frames per second a count of 50 is
            seconds of a filter that rejects every frame because it lost the
            bead (the scanner study sets 0.03 s: the paper's 20 ms burst of
            aberrant frames is shorter).
        flung_restart_sigmas: Restart the track on a frame whose update left the
            estimate more than this many measurement sigmas further from that
            frame than its prior was (a Kalman correction brings the position
            nearer the frame it fuses; across a wall's crest the linearisation,
            the re-prediction through the contact or the projection out of the
            wall along the wrong face can fling it by millimetres).  0 (the
            default): off.  Left out of :func:`~vesselbot_ros.config.to_mapping`
            at 0.
        delay_compensation: Correct at the acquisition time and re-predict.
        history_s: How far back frames can be fused at their acquisition time (s).
        estimate_flow_scale: Estimate ``s``; False freezes it at ``flow_scale0``.
        wall_projection: ``none``: a corrected estimate may lie inside a wall
            (a frame's noise puts it there when the bead rests on the wall),
            and the next prediction's contact force throws it out.  ``lumen``:
            a corrected estimate inside a wall is put back by it with no
            velocity into it (:func:`~vesselbot_ros.physics.kernel.onto_lumen`,
            the projection of a constrained Kalman filter), one brush length
            ``L_0`` from the wall, where the steric force starts (at contact
            the brush would throw the estimate off); and where the estimate
            rests on a wall (within a bead radius of it, pressed towards it by
            the other forces and the control), the covariance's Jacobian
            leaves out the wall's contact and surface forces (their
            microsecond modes give the velocity a gain that throws a delayed
            frame's re-prediction off the wall); elsewhere it holds every
            force.  The mean is predicted with every force, as before.
        wall_constraint_sigma_m: With ``wall_projection: lumen``, where the
            predicted estimate rests on a wall (as above), the covariance is
            conditioned on the wall-normal position being known to this
            standard deviation (m): a pseudo-measurement ``n^T X`` of zero
            innovation (the mean already lies on the lumen's side), the
            constraint "the bead is on this wall" in the covariance as well
            as in the mean.  Without it the covariance keeps the frames' own
            uncertainty across the wall, and through the wall effect's steep
            drag that becomes velocity, then position, uncertainty along the
            floor: the filter then trusts only its last few frames.  0 (the
            default): off.  Left out of
            :func:`~vesselbot_ros.config.to_mapping` at 0.
    """

    measurement_sigma_m: float = 100e-6
    accel_noise_m_per_s2_sqrt_s: float = 0.01
    flow_scale_noise_per_sqrt_s: float = 0.02
    flow_scale0: float = 1.0
    flow_scale_sigma0: float = 0.1
    position_sigma0_m: float = 100e-6
    velocity_sigma0_m_per_s: float = 5e-3
    gate_chi2: float = CHI2_2DOF_999
    max_consecutive_rejections: int = 50
    max_rejection_s: float = 0.0
    flung_restart_sigmas: float = dataclasses.field(default=0.0, metadata={OMIT_IF: lambda v: v == 0.0})
    delay_compensation: bool = True
    history_s: float = 0.25
    estimate_flow_scale: bool = True
    wall_projection: Literal["none", "lumen"] = "none"
    wall_constraint_sigma_m: float = dataclasses.field(default=0.0, metadata={OMIT_IF: lambda v: v == 0.0})

    def __post_init__(self) -> None:
        check_choice("wall_projection", self.wall_projection, ("none", "lumen"))
        check_positive("measurement_sigma_m", self.measurement_sigma_m)
        check_nonnegative("accel_noise_m_per_s2_sqrt_s", self.accel_noise_m_per_s2_sqrt_s)
        check_nonnegative("flow_scale_noise_per_sqrt_s", self.flow_scale_noise_per_sqrt_s)
        check_positive("flow_scale0", self.flow_scale0)
        check_nonnegative("flow_scale_sigma0", self.flow_scale_sigma0)
        check_positive("position_sigma0_m", self.position_sigma0_m)
        check_positive("velocity_sigma0_m_per_s", self.velocity_sigma0_m_per_s)
        check_nonnegative("gate_chi2", self.gate_chi2)
        check_positive("max_consecutive_rejections", self.max_consecutive_rejections)
        check_nonnegative("max_rejection_s", self.max_rejection_s)
        check_nonnegative("flung_restart_sigmas", self.flung_restart_sigmas)
        check_positive("history_s", self.history_s)
        check_nonnegative("wall_constraint_sigma_m", self.wall_constraint_sigma_m)
