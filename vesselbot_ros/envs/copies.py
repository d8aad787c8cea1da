"""N copies of one scenario's compiled loop, stepped in one compiled call: what both environments run.

:class:`LoopCopies` holds the state of N copies of the loop of :mod:`vesselbot_ros.sim.compiled_loop` (the copy on
the first axis of every array) and advances them with :func:`env_kernel`: one numba call that runs
:func:`~vesselbot_ros.sim.compiled_loop.step_copies` (the loop's own tick body: observer, command, coil, plant) and
then writes each copy's observation, reward and end flags.  The scalar environment is one copy
(:class:`~vesselbot_ros.envs.env.VesselbotEnv`), the vector environment N
(:class:`~vesselbot_ros.envs.vector.VesselbotVectorEnv`): the same call, so a seed gives the same bits in both.

Observation of a copy (float64, :func:`~vesselbot_ros.control.policy.observation_fields` names the slices; d = 2
axes (x, z) in the plane, 3 (x, y, z) in a 3-D tree), what a real controller sees after the observer's update at tick k:

=====================  =========  ===========================================================
field                  unit       meaning
=====================  =========  ===========================================================
x_hat_m                m (d)      the observer's position estimate
z_hat_m_per_s          m/s (d)    the observer's velocity estimate
measurement_age_s      s (1)      age of the estimate's last accepted measurement, at most
                                  ``AGE_CAP_S`` = 1 s (before the first measurement)
p_ref_m                m (d)      the reference at tick k
v_ref_m_per_s          m/s (d)    its velocity
a_ref_m_per_s2         m/s^2 (d)  its acceleration
g_applied_T_per_m      T/m (d)    the gradient the coil applied over the last period
sequence_phase         - (1)      the scanner's phase at tick k (0 continuous, 1 tracking, 2 dead, 3
                                  propulsion); only under a multiplexed sequence
p_true_m               m (d)      the true position; only with ``privileged=True``
v_true_m_per_s         m/s (d)    the true velocity; only with ``privileged=True``
=====================  =========  ===========================================================

Reward of a step (its tick k -> k + 1), :class:`RewardParams` (defaults in brackets)::

    r = - |p_true - p_ref| / error_scale_m                       tracking, at tick k + 1   [1 mm]
        - energy_weight * |g_applied|^2 / g_max^2                the gradient's energy      [0.01]
        - lumen_penalty   if the robot's centre left the lumen   (and the episode ends)     [100]
                          (or touched the wall, with contact_ends_episode)
        + outlet_bonus    if it reached the route's outlet       (and the episode ends)     [100]

The episode ends (``terminated``) when the robot's centre leaves the lumen (its penetration of the nearest wall
exceeds its radius: the plant's own wall, in a straight vessel, a planar network or a 3-D tree; the wall's contact
force makes this rare: ``contact_ends_episode`` ends it at the first touch instead) or, on a route
(``reference.route_outlet``), when it comes within ``goal_radius_m`` of the route's end (:func:`route_end`: the
planned reference's last anchor); it is ``truncated`` after the scenario's ``sim.n_ticks`` steps (its duration).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numba
import numpy as np
import numpy.typing as npt
from llvmlite import ir
from numba.core import cgutils, types
from numba.experimental import structref
from numba.extending import intrinsic

from vesselbot_ros.control.policy import AGE_CAP_S, observation_fields
from vesselbot_ros.control.route import planned_reference
from vesselbot_ros.errors import ConfigError
from vesselbot_ros.physics.integrator import OK
from vesselbot_ros.scanner.imager_model import VariateBuffer, queue_columns
from vesselbot_ros.scanner.sequence import phase_codes, sequence_vector
from vesselbot_ros.scanner.stages import seq_imager_state_size
from vesselbot_ros.sim import compiled_loop
from vesselbot_ros.sim.closed_loop import build_stages
from vesselbot_ros.sim.compiled_loop import OP_RESET, OP_SKIP, OP_STEP, step_copies, step_scratch
from vesselbot_ros.sim.kinds import SECTIONS
from vesselbot_ros.sim.scenario import Scenario

__all__ = ["RewardParams", "LoopCopies", "LoopState", "env_kernel", "env_steps", "observation_fields", "route_end", "AGE_CAP_S", "OP_STEP",
           "OP_RESET", "OP_SKIP"]


@dataclasses.dataclass(frozen=True)
class RewardParams:
    """The reward and the end of an episode (module docstring).

    Attributes:
        error_scale_m: The tracking error that costs 1 per step (m).
        energy_weight: Weight of the applied gradient's squared norm over the coil's maximum squared.
        lumen_penalty: Subtracted on the step the robot's centre leaves the lumen.
        outlet_bonus: Added on the step the robot reaches the route's outlet (routes only).
        goal_radius_m: Distance to the route's end that counts as reached (m).
        contact_ends_episode: Wall contact (any penetration) ends the episode as leaving the lumen does, with its
            penalty (a stricter task: fly without touching the wall).
    """

    error_scale_m: float = 1.0e-3
    energy_weight: float = 0.01
    lumen_penalty: float = 100.0
    outlet_bonus: float = 100.0
    goal_radius_m: float = 0.5e-3
    contact_ends_episode: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.contact_ends_episode, bool):
            raise ConfigError(f"reward.contact_ends_episode must be true or false, got {self.contact_ends_episode!r}")
        for f in dataclasses.fields(self):
            if f.name == "contact_ends_episode":
                continue
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0.0):
                raise ConfigError(f"reward.{f.name} must be a finite number >= 0, got {v!r}")
        if self.error_scale_m <= 0.0 or self.goal_radius_m <= 0.0:
            name = "error_scale_m" if self.error_scale_m <= 0.0 else "goal_radius_m"
            raise ConfigError(f"reward.{name} must be > 0, got {getattr(self, name)!r}")

    def vector(self) -> npt.NDArray[np.float64]:
        """The (6,) array :func:`env_kernel` reads."""
        return np.array([self.error_scale_m, self.energy_weight, self.lumen_penalty, self.outlet_bonus,
                         self.goal_radius_m, 1.0 if self.contact_ends_episode else 0.0])


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on its ~80 arrays
def env_steps(lo, hi, ops, ticks, actions, n_steps, dt, ts, p_ref, v_ref, a_ref, phase, plant_geom, ig, variates,  # type: ignore[no-untyped-def]  # numba: types at compile time
               imager_prm, outliers, dropouts, queue, seq_state, img_state, obs_step_address, obs_prm, obs_state,
               obs_istate, obs_geom, obs_work, obs_state0, obs_istate0, obs_work0, coil_prm, seq_mode, sv, hold_s, y, contact,
               coil_state, plant_stats, model_stats, h, ga, y0, coil_state0, p_true, v_true, delta_m, in_contact,
               contact_phase, meas_p, meas_t_acq_s, meas_outlier, x_hat, z_hat, flow_scale_hat,
               magnetization_scale_hat, meas_used, meas_rejected, u_cmd, g_cmd, g_applied, k_scale, saturated,
               slew_limited, cmd_status, cmd_rejected, obs_out, err, codes, rw, robot_radius_m, goal, has_goal,
               privileged, obs, reward, terminated, truncated, rejected, scratch):
    """:func:`~vesselbot_ros.sim.compiled_loop.step_copies` of copies ``lo .. hi-1``, then each stepped or reset copy's observation row
    ``obs[i]``, ``reward[i]``, ``terminated[i]``, ``truncated[i]`` and its count of rejected commands
    ``rejected[i]`` (module docstring); returns ``(copies that stopped, copies whose draws run low)``.  ``rw`` is
    :meth:`RewardParams.vector`; ``phase`` the sequence's phase per tick
    (empty: no sequence); ``goal`` the route's end (``has_goal``); ``privileged`` adds the true state; ``scratch``
    :func:`~vesselbot_ros.sim.compiled_loop.step_scratch`'s (one per thread).  :func:`env_kernel` calls it with
    the arrays of a :class:`LoopState`."""
    step_copies(lo, hi, ops, ticks, actions, dt, ts, plant_geom, ig, variates, imager_prm, outliers, dropouts, queue,
                seq_state, img_state, obs_step_address, obs_prm, obs_state, obs_istate, obs_geom, obs_work, obs_state0,
                obs_istate0, obs_work0, coil_prm, seq_mode, sv, hold_s, y, contact, coil_state, plant_stats,
                model_stats, h, ga, y0, coil_state0, p_true, v_true, delta_m, in_contact, contact_phase, meas_p,
                meas_t_acq_s, meas_outlier, x_hat, z_hat, flow_scale_hat, magnetization_scale_hat, meas_used,
                meas_rejected, u_cmd, g_cmd, g_applied, k_scale, saturated, slew_limited, cmd_status, cmd_rejected,
                obs_out, err, codes, scratch)
    d = x_hat.shape[1]
    g_max = coil_prm[0]
    failed = 0
    low = 0
    for i in range(lo, hi):
        if variates[i, 0] + 2 * d > variates.shape[1] - 1:  # after the step: fewer draws left than an acquisition's
            low += 1
    for i in range(lo, hi):
        if ops[i] == OP_SKIP:
            continue
        if codes[i] != OK:
            failed += 1
            continue
        k = ticks[i]
        o = obs[i]
        for c in range(d):
            o[c] = x_hat[i, c]
            o[d + c] = z_hat[i, c]
            o[2 * d + 1 + c] = p_ref[k, c]
            o[3 * d + 1 + c] = v_ref[k, c]
            o[4 * d + 1 + c] = a_ref[k, c]
            o[5 * d + 1 + c] = ga[i, c]
        o[2 * d] = min(obs_out[i, 2 * d], AGE_CAP_S)  # inf before the first measurement
        at = 6 * d + 1
        if phase.shape[0] > 0:
            o[at] = phase[k]
            at += 1
        if privileged:
            for c in range(d):
                o[at + c] = p_true[i, c]
                o[at + d + c] = v_true[i, c]
        if ops[i] == OP_RESET:
            reward[i] = 0.0
            terminated[i] = False
            truncated[i] = False
            rejected[i] = 0
            continue
        if cmd_rejected[i] != 0:
            rejected[i] += 1
        e2 = 0.0
        g2 = 0.0
        r2 = 0.0
        for c in range(d):
            e = p_true[i, c] - p_ref[k, c]
            e2 += e * e
            g2 += g_applied[i, c] * g_applied[i, c]
            if has_goal:
                q = p_true[i, c] - goal[c]
                r2 += q * q
        outside = delta_m[i] > robot_radius_m or (rw[5] > 0.5 and delta_m[i] > 0.0)
        reached = has_goal and math.sqrt(r2) <= rw[4]
        r = -math.sqrt(e2) / rw[0] - rw[1] * g2 / (g_max * g_max)
        if outside:
            r -= rw[2]
        elif reached:
            r += rw[3]
        reward[i] = r
        terminated[i] = outside or reached
        truncated[i] = k >= n_steps and not terminated[i]
    return failed, low


@structref.register
class LoopStateType(types.StructRef):
    """The numba type of a :class:`LoopState` (its field's type: the arrays' and the scenario's)."""

    def preprocess_fields(self, fields):  # type: ignore[no-untyped-def]  # numba: types at compile time
        return tuple((name, types.unliteral(typ)) for name, typ in fields)


class LoopState(structref.StructRefProxy):
    """Every array :func:`env_steps` reads and writes, and a scratch per thread, in one numba object (built once per
    :class:`LoopCopies`): a call of :func:`env_kernel` unboxes one argument, not ~80 (their unboxing was ~6 us a
    step).  ``args`` is ``(env_steps' arguments after lo and hi, without scratch; the scratch arrays of
    step_scratch, each stacked on a first axis, ``_SLOT_ROWS`` rows per thread)``; the arrays are the caller's (no copy)."""


structref.define_proxy(LoopState, LoopStateType, ["args"])


@numba.njit(cache=True)
def new_loop_state(args):  # type: ignore[no-untyped-def]  # numba: types at compile time
    """A :class:`LoopState` holding ``args`` (its docstring)."""
    return LoopState(args)


@intrinsic
def _borrowed_args(typingctx, state):  # type: ignore[no-untyped-def]  # numba intrinsic: typed at compile time
    """``state.args`` read without numba's runtime, for a caller compiled without it: no reference counts (the
    state, held by the caller's argument for the whole call, holds the arrays).  The payload's pointer is read as
    ``NRT_MemInfo_data_fast`` reads it: the 4th word of numba's ``NRT_MemInfo {refct, dtor, dtor_info, data, ...}``."""
    def codegen(context, builder, sig, args):  # type: ignore[no-untyped-def]  # numba's codegen hook: typed by numba
        ref = cgutils.create_struct_proxy(sig.args[0])(context, builder, value=args[0])
        head = ir.LiteralStructType([cgutils.intp_t, cgutils.voidptr_t, cgutils.voidptr_t, cgutils.voidptr_t])
        data = builder.load(cgutils.gep_inbounds(builder, builder.bitcast(ref.meminfo, head.as_pointer()), 0, 3))
        payload_type = sig.args[0].get_data_type()
        ptr = builder.bitcast(data, context.data_model_manager[payload_type].get_value_type().as_pointer())
        return cgutils.create_struct_proxy(payload_type)(context, builder, ref=ptr).args

    return state.field_dict["args"](state), codegen


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts
def _env_state_steps(lo, hi, slot, state):  # type: ignore[no-untyped-def]  # numba: types at compile time
    args, scratch, _io = _borrowed_args(state)  # type: ignore[call-arg, var-annotated]  # the intrinsic takes the typing context itself
    work, fbuf, sc, fk, acq, img_out, coil_out, gc, zd, forces = scratch
    return env_steps(lo, hi, *args, (work[slot], fbuf[slot], sc[slot], fk[slot], acq[slot], img_out[slot],
                                     coil_out[slot], gc[slot], zd[slot], forces[slot]))


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts
def _env_state_step_one(state, action):  # type: ignore[no-untyped-def]  # numba: types at compile time
    _args, _scratch, io = _borrowed_args(state)  # type: ignore[call-arg, var-annotated]  # the intrinsic takes the typing context itself
    actions, reward, terminated, truncated, ticks, rejected = io
    if action.shape[0] != actions.shape[1]:
        return -1, 0, 0.0, False, False, 0, 0
    for c in range(action.shape[0]):
        actions[0, c] = action[c]
    failed, low = _env_state_steps(0, 1, 0, state)  # copy 0, the first thread's scratch slot
    return failed, low, reward[0], terminated[0], truncated[0], ticks[0], rejected[0]


@numba.njit(cache=True, nogil=True)
def env_step_one(state, action):  # type: ignore[no-untyped-def]  # numba: types at compile time
    """The scalar environment's step: copy 0 of ``state`` (its ``ops[0]`` set) under ``action`` ((d,) float64, copied
    into the copy's action row), in one call; returns ``(failed, low, reward, terminated, truncated, tick,
    rejected)`` (``failed`` -1: ``action`` is not d long, nothing stepped)."""
    return _env_state_step_one(state, action)


@numba.njit(cache=True, nogil=True)
def env_kernel(lo, hi, slot, state):  # type: ignore[no-untyped-def]  # numba: types at compile time
    """:func:`env_steps` of copies ``lo .. hi-1`` on the arrays of ``state`` (a :class:`LoopState`), with the
    scratch at row ``slot`` of the stacked scratch (a thread's slot times ``_SLOT_ROWS``); returns ``(copies that
    stopped, copies whose draws run low)``.  Compiled with numba's runtime, so the one reference to ``state`` its
    call takes is given back; the steps run without it."""
    return _env_state_steps(lo, hi, slot, state)


class LoopCopies:
    """N copies of ``scenario``'s loop, the controller's command replaced by outside ones (module docstring).

    Args:
        scenario: The scenario (its imager, observer, coil, plant and reference, all of kinds the compiled loop
            runs; its controller is not used).
        copies: N.
        threads: Threads that step disjoint ranges of the copies at once (1: the caller's thread).
        privileged: Add the true position and velocity to the observation.
        reward: The reward's parameters.

    Raises:
        ConfigError: a stage the compiled loop cannot run (e.g. ``imager.kind: mr_images``), named in one line.
    """

    def __init__(self, scenario: Scenario, copies: int, privileged: bool = False,
                 reward: RewardParams | None = None, threads: int = 1) -> None:
        if int(copies) < 1:
            raise ConfigError(f"copies must be >= 1, got {copies!r}")
        if int(threads) < 1:
            raise ConfigError(f"threads must be >= 1, got {threads!r}")
        self.threads = min(int(threads), int(copies))
        self._pool: ThreadPoolExecutor | None = None
        self.scenario = scenario
        self.n = n = int(copies)
        self.privileged = bool(privileged)
        self.reward_params = reward if reward is not None else RewardParams()
        self.n_steps = scenario.sim.n_ticks
        stages = build_stages(scenario, None)
        # one tick more than the run: the observation after the last step is the observer's at tick n_ticks
        inp, bad = compiled_loop.try_prepare(stages, self.n_steps + 1, scenario.sim.dt_control_s, False)
        if inp is None:
            kinds_named = ", ".join(f"{_section(r)}.kind {getattr(getattr(scenario, _section(r)), 'kind', '?')!r}"
                                    for r in bad)
            raise ConfigError(f"scenario {scenario.name!r}: the environment steps the compiled loop, which cannot run "
                              f"its {kinds_named}")
        self.inp = inp
        d = self.dims = inp.dims
        self.sequenced = inp.seq_mode == 1
        self.g_max_T_per_m = float(inp.coil_prm[0])
        self.fields = observation_fields(d, self.sequenced, self.privileged)
        self.obs_size = self.fields[-1][1].stop
        phase = (phase_codes(sequence_vector(scenario.sequence), inp.ts).astype(np.float64) if self.sequenced
                 else np.zeros(0))
        route = bool(getattr(scenario.reference, "route_outlet", ""))
        goal = route_end(scenario) if route else np.zeros(d)
        obs0 = inp.obs
        self.ops = np.full(n, OP_SKIP, dtype=np.int64)
        self.ticks = np.zeros(n, dtype=np.int64)
        self.actions = np.zeros((n, d))
        self.per = 2 * d
        self.variates = np.zeros((n, 1 + self.per * VariateBuffer.BLOCK))
        self.buffers: list[VariateBuffer | None] = [None] * n
        spec = compiled_loop.columns(d)
        self.cols = {name: np.zeros((n, *shape), dtype=dt) for name, dt, shape in spec}
        self.state = {
            "queue": np.zeros((n, self.n_steps + 2, queue_columns(d))),
            "seq_state": np.zeros((n, seq_imager_state_size(d))),
            "img_state": np.zeros((n, 4)),
            "obs_state": np.zeros((n, obs0.state0.shape[0])),
            "obs_istate": np.zeros((n, obs0.istate0.shape[0]), dtype=np.int64),
            "obs_work": np.zeros((n, obs0.work0.shape[0])),
            "y": np.zeros((n, 2 * d)),
            "contact": np.zeros((n, 4)),
            "coil_state": np.zeros((n, inp.coil_state0.shape[0])),
            "plant_stats": np.zeros((n, 4), dtype=np.int64),
            "model_stats": np.zeros((n, 4), dtype=np.int64),
            "h": np.zeros(n),
            "ga": np.zeros((n, d)),
        }
        self.obs_out = np.zeros((n, 3 * d + 4))
        self.err = np.zeros((n, 3 + 2 * d + 1))
        self.codes = np.zeros(n, dtype=np.int64)
        self.obs = np.zeros((n, self.obs_size))
        self.reward = np.zeros(n)
        self.terminated = np.zeros(n, dtype=np.bool_)
        self.truncated = np.zeros(n, dtype=np.bool_)
        self.rejected = np.zeros(n, dtype=np.int64)
        st, c = self.state, self.cols
        self._args: tuple[Any, ...] = (
            self.ops, self.ticks, self.actions, self.n_steps, inp.dt, inp.ts, inp.p_ref, inp.v_ref, inp.a_ref, phase,
            inp.plant_geom, inp.ig, self.variates, inp.imager_prm, inp.outliers, inp.dropouts, st["queue"],
            st["seq_state"], st["img_state"], inp.obs_step.address, obs0.prm, st["obs_state"], st["obs_istate"], obs0.geom,
            st["obs_work"], obs0.state0, obs0.istate0, obs0.work0, inp.coil_prm, inp.seq_mode, inp.sv, inp.hold_s,
            st["y"], st["contact"], st["coil_state"], st["plant_stats"], st["model_stats"], st["h"], st["ga"],
            inp.plant_y0, inp.coil_state0, *(c[name] for name, _dt, _shape in spec), self.obs_out, self.err,
            self.codes, self.reward_params.vector(), float(scenario.physics.robot.radius_m), goal, route,
            self.privileged, self.obs, self.reward, self.terminated, self.truncated, self.rejected,
        )
        # one slot per thread, _SLOT_ROWS rows apart: no two threads' scratch on one cache line
        scratch = tuple(np.stack([a] * (self.threads * _SLOT_ROWS)) for a in step_scratch(d))
        #: Every array above in one numba object (:class:`LoopState`), and :func:`env_kernel`'s compiled entry
        #: for its type: ``step(lo, hi, row, state_ref)`` steps copies ``lo .. hi-1`` with the scratch at row ``row`` (a thread's
        #: slot times _SLOT_ROWS) and returns ``(failed, low)`` (:meth:`settle`).
        io = (self.actions, self.reward, self.terminated, self.truncated, self.ticks, self.rejected)
        self.state_ref = new_loop_state((self._args, scratch, io))
        self.step = _entry_point(self.state_ref)
        #: :func:`env_step_one`'s compiled entry (the scalar environment's step: ``step_one(state_ref, action)``); its
        #: ``action`` must be a one-dimensional float64 ndarray (any strides): the entry checks no type.
        self.step_one = _entry_point(self.state_ref, one=True)
        edges = np.linspace(0, n, self.threads + 1).astype(int)
        self._ranges = [(int(a), int(b)) for a, b in itertools.pairwise(edges)]

    def seed(self, i: int, rng: np.random.Generator) -> None:
        """Copy ``i``'s imager draws from ``rng`` from now on (the Generator the run's seed makes)."""
        b = self.buffers[i] = VariateBuffer(rng, self.dims, self.variates[i])
        b.ready()

    def run(self) -> None:
        """Advance every copy by its ``ops`` entry (``actions`` set by the caller), in one compiled call (every copy
        stepped or reset must have been seeded: :meth:`seed`).

        Raises:
            ModelInputError: a copy's loop stopped (the per-tick loop's words; :func:`raise_for_code`).
        """
        if self.threads == 1:
            failed, low = self.step(0, self.n, 0, self.state_ref)
        else:  # disjoint ranges of copies, one per thread, each its scratch slot (the kernel releases the GIL); the
            # calling thread takes the first range itself (one hand-off fewer per step)
            if self._pool is None:
                self._pool = ThreadPoolExecutor(max_workers=self.threads - 1)
            futures = [self._pool.submit(self.step, a, b, slot * _SLOT_ROWS, self.state_ref)
                       for slot, (a, b) in enumerate(self._ranges) if slot > 0]
            a0, b0 = self._ranges[0]
            results = [self.step(a0, b0, 0, self.state_ref)] + [f.result() for f in futures]
            failed, low = sum(int(r[0]) for r in results), sum(int(r[1]) for r in results)
        if failed or low:
            self.settle(failed, low)

    def settle(self, failed: int, low: int) -> None:
        """After a call of :attr:`step` that returned ``(failed, low)`` (either nonzero): refill the copies whose draws
        run low, then raise if a copy stopped (:meth:`run`'s words).  The scalar environment calls :attr:`step`
        itself (one copy, no thread) and this only when needed.

        Raises:
            ModelInputError: a copy's loop stopped (the per-tick loop's words; :func:`raise_for_code`).
        """
        if low:  # a block of draws per copy lasts 256 acquisitions: refill the copies that run low before the next
            for j in np.flatnonzero(self.variates[:, 0] + self.per > self.variates.shape[1] - 1):
                b = self.buffers[j]
                if b is not None:
                    b.ready()
        if failed:
            i = int(np.flatnonzero(self.codes)[0])
            compiled_loop.raise_for_code(int(self.codes[i]), int(self.ticks[i]), self.state["y"][i], self.err[i],
                                         self.inp.obs.message)

    def close(self) -> None:
        """Stop the threads (if any); :meth:`run` starts them again."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None


#: Rows of the stacked scratch between two threads' slots (the smallest slot, (d,) float64, 16 bytes: 8 rows, 128
#: bytes, a cache line and its neighbour the prefetcher pulls; adjacent slots were shared between threads).
_SLOT_ROWS = 8


def _entry_point(state: LoopState, one: bool = False) -> Any:
    """:func:`env_kernel`'s compiled entry for ``state``'s type, or :func:`env_step_one`'s (``one``) (compiled, or
    loaded from numba's cache, by a call that steps no copy: a range of none, an action of no length): called
    directly, it skips the dispatcher's typing of the arguments (~0.5 us a step)."""
    if one:
        probe: tuple[Any, ...] = (state, np.zeros(8)[::2])  # any layout (a strided action read as it is); 4 long: no step
        env_step_one(*probe)
        return env_step_one.overloads[tuple(numba.typeof(v) for v in probe)].entry_point  # type: ignore[attr-defined]  # set on every compiled overload
    env_kernel(0, 0, 0, state)
    sig = tuple(numba.typeof(v) for v in (0, 0, 0, state))
    return env_kernel.overloads[sig].entry_point  # type: ignore[attr-defined]  # set on every compiled overload


def route_end(scenario: Scenario) -> npt.NDArray[np.float64]:
    """The end of the scenario's route (its planned reference's last anchor, m, (d,)): the goal of a route's episode."""
    ref = planned_reference(scenario)
    axes = ("x", "y", "z") if scenario.dims == 3 else ("x", "z")
    return np.array([float(getattr(ref, f"anchors_{a}_m")[-1]) for a in axes])


def _section(role: str) -> str:
    return SECTIONS[role]
