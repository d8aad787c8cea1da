"""A controller that replays recorded gradient commands, one per control tick: an environment episode's actions.

The controller kind ``action_replay`` (:mod:`vesselbot_ros.sim.kinds`) commands, at tick ``k`` (``t = k dt``), row
``k`` of a (m, d) array of gradients (T/m; d the vessel's axes), and zero after its last row.  Its commands are bare
gradients, as an agent's actions in :mod:`vesselbot_ros.envs` are: no acceleration asked for (``u_cmd`` NaN), status
``ok``, the observer's flow scale; a NaN or infinite row is rejected by the loop as any non-finite command is (the
coil ramps to zero).  So an episode's actions replayed through ``vesselbot simulate`` give the episode's bits::

    vesselbot simulate --config sound_small_artery --seed 3 \\
        --set controller.kind=action_replay --set controller.actions_file=episode.npy

The compiled loop runs it (:meth:`ActionReplayController.compiled`); the per-tick loop calls
:meth:`ActionReplayController.command`; both read the same row.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.backstepping import ControlCommand
from vesselbot_ros.control.compiled_stage import CompiledController, lazy_step

__all__ = ["ActionReplayParams", "ActionReplayController", "load_actions", "action_replay_step"]


@dataclasses.dataclass(frozen=True)
class ActionReplayParams:
    """Parameters of the ``action_replay`` controller.

    Attributes:
        kind: ``action_replay``.
        actions_file: A ``.npy`` file of the commands, (m, d) float (T/m), row k at tick k.
    """

    kind: str = "action_replay"
    actions_file: str = ""


def load_actions(path: str | Path, dims: int) -> npt.NDArray[np.float64]:
    """The (m, dims) commands of a ``.npy`` file.

    Raises:
        ConfigError: no such file, or not an (m, dims) array of numbers, naming ``controller.actions_file``.
    """
    if not str(path):
        raise ConfigError("controller.actions_file: the action_replay controller needs a .npy file of commands (T/m)")
    try:
        a = np.load(Path(path), allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ConfigError(f"controller.actions_file: cannot read {str(path)!r}: {exc}") from None
    if a.ndim != 2 or a.shape[1] != dims or not np.issubdtype(a.dtype, np.number):
        raise ConfigError(f"controller.actions_file: {str(path)!r} holds a {a.dtype} array of shape {a.shape}, expected "
                          f"(ticks, {dims}) gradients (T/m)")
    return np.ascontiguousarray(a, dtype=np.float64)


# ---- the compiled loop's form (control/compiled_stage.py) -------------------------------------------------------
# prm: [dt (s), m, commands (m * d, row-major)]; state, work: unused (empty)
def _replay_step(prm, state, geom, work, fbuf, sc, t, est, pr, vr, ar, out):  # type: ignore[no-untyped-def]  # numba kernel: typed by controller_step_type
    """Row ``round(t / dt)`` of the commands (zero past the last), as a bare gradient."""
    d = pr.shape[0]
    k = int(math.floor(t / prm[0] + 0.5))
    m = int(prm[1])
    for c in range(d):
        out[c] = prm[2 + k * d + c] if 0 <= k < m else 0.0
        out[d + c] = np.nan
    out[2 * d] = est[2 * d + 1]
    out[2 * d + 1] = 1.0
    return 0


action_replay_step = lazy_step(_replay_step, nrt=False)


class ActionReplayController:
    """Row ``k`` of ``actions`` (T/m, (m, d)) at tick ``k``, zero after the last (module docstring).

    Args:
        actions: The commands, one row per tick.
        dt_s: The control period (s): tick ``k`` is ``t = k dt_s``.
    """

    def __init__(self, actions: npt.ArrayLike, dt_s: float) -> None:
        self.actions = np.array(actions, dtype=np.float64, order="C", ndmin=2)
        self.dims = int(self.actions.shape[1])
        self.dt_s = float(dt_s)

    def command(self, t_s: float, estimate: Any, ref: Any) -> ControlCommand:
        """The command of the tick at ``t_s`` (the same row as the compiled step)."""
        k = int(math.floor(t_s / self.dt_s + 0.5))
        g = self.actions[k].copy() if 0 <= k < self.actions.shape[0] else np.zeros(self.dims)
        return ControlCommand(g, np.full(self.dims, np.nan), "ok")

    def compiled(self) -> CompiledController:
        """This controller in the compiled loop's form."""
        prm = np.concatenate([[self.dt_s, float(self.actions.shape[0])], self.actions.reshape(-1)])
        return CompiledController(action_replay_step, prm, np.zeros(0), 0)
