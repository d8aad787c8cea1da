"""A user's controller as a stage kind: one class, named in a scenario by ``module:Class``.

Unlike ``examples/my_controller.py`` (a ROS node of your own in the controller's
slot), this controller is a *stage kind*: the package builds it and calls it, so
the same class runs, with the same numbers, in

* ``vesselbot simulate`` (the ROS-free loop),
* ``vesselbot campaign`` (on Dask workers, local or behind ``--scheduler``),
* ``vesselbot run`` (inside the graph's controller node).

Name it in a scenario (or with ``--set``); the module must be importable, for
instance from this folder::

    PYTHONPATH=examples vesselbot simulate --set controller.kind=plugin_controller:FeedforwardPD
    PYTHONPATH=examples vesselbot simulate --set controller.kind=plugin_controller:FeedforwardPD \\
        --set controller.kp_per_s2=900

or in YAML::

    controller:
      kind: plugin_controller:FeedforwardPD
      kp_per_s2: 900.0
      kd_per_s: 60.0

The convention (``vesselbot kinds`` lists the registered kinds; the registry
is :mod:`vesselbot_ros.sim.kinds`):

* ``ROLE``: the role the class fills (``controller`` here);
* ``Params``: a frozen dataclass with a ``kind: str`` field; the scenario's
  section is loaded into it by the package's config loader, so unknown keys
  and bad values are errors naming the key;
* ``__init__(params, context)``: ``context`` is a
  :class:`~vesselbot_ros.sim.kinds.BuildContext`: the scenario, the seed, the
  control period and the controller's model of the plant (``context.model``,
  with ``model.overrides`` applied, e.g. a blood-velocity error);
* the role's method: ``command(t_s, estimate, ref) -> ControlCommand``, with
  ``estimate`` the graph's estimate (``x_hat``, ``z_hat``,
  ``time_since_measurement_s``, ``flow_scale``) and ``ref`` the reference
  sample (``p``, ``v``, ``a``).  The coil stage saturates and slews whatever
  it returns.

An installed package registers kinds once for every scenario through the
entry point group ``vesselbot_ros.stages`` (in its pyproject.toml)::

    [project.entry-points."vesselbot_ros.stages"]
    feedforward_pd = "my_lab.control:FeedforwardPD"

and a scenario then says ``controller: {kind: feedforward_pd}``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.backstepping import ControlCommand
from vesselbot_ros.control.bspline_reference import RefSample
from vesselbot_ros.control.estimate import Estimate
from vesselbot_ros.sim.kinds import BuildContext


@dataclasses.dataclass(frozen=True)
class FeedforwardPDParams:
    """Gains of :class:`FeedforwardPD` (the ``controller`` section of a scenario).

    Attributes:
        kind: The kind's name, as the scenario gives it.
        kp_per_s2: Position gain (1/s^2).
        kd_per_s: Velocity gain (1/s).
    """

    kind: str = "plugin_controller:FeedforwardPD"
    kp_per_s2: float = 600.0
    kd_per_s: float = 50.0

    def __post_init__(self) -> None:
        for name in ("kp_per_s2", "kd_per_s"):
            value = getattr(self, name)
            if not value > 0.0:
                raise ConfigError(f"{name} must be > 0, got {value!r}")


class FeedforwardPD:
    """PD on the tracking error, with the model's forces fed forward: U = a_ref + kd (v_ref - z) + kp (p_ref - x) - F."""

    ROLE = "controller"
    Params = FeedforwardPDParams

    def __init__(self, params: FeedforwardPDParams, context: BuildContext) -> None:
        self.params = params
        self.model = context.model
        self.b_inv = np.linalg.inv(self.model.input_matrix)  # acceleration (m/s^2) -> gradient (T/m)

    def command(self, t_s: float, estimate: Estimate, ref: RefSample) -> ControlCommand:
        x, z = estimate.x_hat, estimate.z_hat
        f = self.model.F(t_s, x, z, estimate.flow_scale)
        u = ref.a + self.params.kd_per_s * (ref.v - z) + self.params.kp_per_s2 * (ref.p - x) - f
        return ControlCommand(self.b_inv @ u, u, "ok")
