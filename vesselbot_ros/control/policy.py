"""A learned policy as a controller: a user's ``module:callable`` from the environments' observation to a gradient.

The environments of :mod:`vesselbot_ros.envs` give an agent an observation vector (:func:`observation_fields`:
the estimate, the age of its last measurement, the reference, the gradient the coil applied over the last period,
the scanner's phase) and take its action, the tick's gradient command (T/m).  The controller kind ``policy``
(:mod:`vesselbot_ros.sim.kinds`) runs the same callable in the controller's place of any loop::

    controller:
      kind: policy
      policy: my_lab.agents:act          # act(observation: ndarray) -> gradient (d,), T/m

so a policy trained in an environment runs, by name, in ``vesselbot simulate`` and ``vesselbot campaign`` with the
numbers it has in the environment (``test/unit/control/test_policy.py``).  The controller builds the observation
from what it receives (the estimate, the reference sample) and from a replica of the scenario's coil that it drives
with its own commands (the coil's output depends only on the commands and the times, so the replica's applied
gradient is the coil's).  The replica misses a tick on which the controller is not called (a non-finite estimate):
the coil then ramps towards zero on its own.  The true state is never given (a policy trained with
``privileged=True`` cannot run here).
"""

from __future__ import annotations

import dataclasses
import importlib
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.backstepping import ControlCommand
from vesselbot_ros.scanner.sequence import SequenceParams, phase_codes, sequence_vector

__all__ = ["PolicyParams", "PolicyController", "load_policy", "observation_fields", "AGE_CAP_S"]

#: The observation's measurement age is capped here (s): inf before the first measurement, and a controller treats any
#: age past its stale timeout alike.
AGE_CAP_S = 1.0


def observation_fields(dims: int, sequenced: bool, privileged: bool) -> tuple[tuple[str, slice], ...]:
    """``(name, slice)`` of each field of the environments' observation vector, in order (the table of
    :mod:`vesselbot_ros.envs.copies`): ``x_hat_m``, ``z_hat_m_per_s`` (d each), ``measurement_age_s`` (1, at most
    :data:`AGE_CAP_S`), ``p_ref_m``, ``v_ref_m_per_s``, ``a_ref_m_per_s2``, ``g_applied_T_per_m`` (d each), then
    ``sequence_phase`` (1) under a multiplexed sequence and ``p_true_m``, ``v_true_m_per_s`` (d each) if
    ``privileged``."""
    sizes = [("x_hat_m", dims), ("z_hat_m_per_s", dims), ("measurement_age_s", 1), ("p_ref_m", dims),
             ("v_ref_m_per_s", dims), ("a_ref_m_per_s2", dims), ("g_applied_T_per_m", dims)]
    if sequenced:
        sizes.append(("sequence_phase", 1))
    if privileged:
        sizes += [("p_true_m", dims), ("v_true_m_per_s", dims)]
    out, at = [], 0
    for name, n in sizes:
        out.append((name, slice(at, at + n)))
        at += n
    return tuple(out)


@dataclasses.dataclass(frozen=True)
class PolicyParams:
    """Parameters of the ``policy`` controller.

    Attributes:
        kind: ``policy``.
        policy: ``module:callable``: ``callable(observation) -> gradient`` (T/m, (d,)); the module must be importable
            (e.g. on ``PYTHONPATH``).
    """

    kind: str = "policy"
    policy: str = ""


def load_policy(name: str) -> Callable[[npt.NDArray[np.float64]], Any]:
    """The callable ``module:attr`` names.

    Raises:
        ConfigError: not ``module:attr``, a module that does not import, or no such callable, naming
            ``controller.policy``.
    """
    module_name, _, attr = str(name).partition(":")
    if not module_name or not attr:
        raise ConfigError(f"controller.policy must be 'module:callable', got {name!r}")
    try:
        module = importlib.import_module(module_name)
    except Exception as exc:  # noqa: BLE001 - any failure of a user's module is one line naming the key
        raise ConfigError(f"controller.policy: module {module_name!r} does not import: {type(exc).__name__}: {exc}") from None
    obj: Any = module
    for part in attr.split("."):
        obj = getattr(obj, part, None)
    if not callable(obj):
        raise ConfigError(f"controller.policy: module {module_name!r} has no callable {attr!r}")
    policy: Callable[[npt.NDArray[np.float64]], Any] = obj
    return policy


class PolicyController:
    """``policy(observation)`` as the tick's command (module docstring).

    Args:
        policy: The callable.
        coil: A replica of the scenario's coil (a fresh ``CoilLimiter`` or ``SequencedCoil``, as the loop's), driven
            by this controller's commands.
        sequence: The scanner's sequence (the observation's phase under a multiplexed one).
        dims: The vessel's axes.
    """

    def __init__(self, policy: Callable[[npt.NDArray[np.float64]], Any], coil: Any, sequence: SequenceParams,
                 dims: int) -> None:
        self.policy = policy
        self.coil = coil
        self.dims = int(dims)
        self._sv = sequence_vector(sequence) if sequence.mode == "multiplexed" else None
        self.fields = observation_fields(self.dims, self._sv is not None, False)
        self._obs = np.zeros(self.fields[-1][1].stop)
        self._applied = np.zeros(self.dims)

    def observation(self, t_s: float, estimate: Any, ref: Any) -> npt.NDArray[np.float64]:
        """The environments' observation at ``t_s`` (a fresh array)."""
        d, o = self.dims, self._obs
        o[0:d] = estimate.x_hat
        o[d:2 * d] = estimate.z_hat
        o[2 * d] = min(float(estimate.time_since_measurement_s), AGE_CAP_S)
        o[2 * d + 1:3 * d + 1] = ref.p
        o[3 * d + 1:4 * d + 1] = ref.v
        o[4 * d + 1:5 * d + 1] = ref.a
        o[5 * d + 1:6 * d + 1] = self._applied
        if self._sv is not None:
            o[6 * d + 1] = float(phase_codes(self._sv, np.array([float(t_s)]))[0])
        return o.copy()

    def command(self, t_s: float, estimate: Any, ref: Any) -> ControlCommand:
        """The policy's gradient for the tick (a bare command: no acceleration asked for)."""
        nan = np.full(self.dims, np.nan)
        try:
            raw = self.policy(self.observation(t_s, estimate, ref))
            g = np.array(raw, dtype=np.float64).reshape(-1) if np.ndim(raw) == 1 else nan
        except Exception:
            self._applied = self.coil.apply(t_s, nan).applied  # the coil gets a rejected command: so does the replica
            raise
        if g.shape != (self.dims,):
            self._applied = self.coil.apply(t_s, nan).applied
            return ControlCommand(np.asarray(raw), nan, "ok")  # the loop rejects it as not a command
        self._applied = self.coil.apply(t_s, g if all(math.isfinite(v) for v in g) else nan).applied
        return ControlCommand(g, nan, "ok")
