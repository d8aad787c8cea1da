"""A lower bound on the position estimation error of every causal estimator fed a run's frames, on any axes.

:func:`run_bound` takes one closed-loop run (:func:`~vesselbot_ros.sim.closed_loop.run_closed_loop`'s
time series) and returns, at every tick, the posterior Cramér-Rao bound (PCRB) on the mean-square position
error of an estimator that has the frames delivered by that tick; :func:`estimation_bound` does it over
seeds and sets it against the observer that flew each run.

What the bound assumes (each makes it hold for more estimators, or says for which it holds):

* **Plant.** The state is ``(X, Xd, s)`` on the vessel's ``d`` axes (two in a straight vessel or a planar
  network, three in a tree: :attr:`~vesselbot_ros.control.model.DynamicsModel.dims`), ``2 d + 1`` numbers.
  ``Xdd = F(t, X, Xd; s) + B g`` is the true plant's (``scenario.physics``, not the controller's model), known
  exactly but for ``s``, the scale of the blood's centreline velocity, constant over the run.  The applied
  gradient ``g`` is known (it is the loop's own output, and ``B`` does not depend on the state), so it adds no
  uncertainty.  No process noise: the simulated plant has none.
* **Prior.** Independent Gaussians at ``t = 0``: position ``prior_position_sigma_m`` (1 mm) and velocity
  ``prior_velocity_sigma_m_per_s`` (10 mm/s) per axis, about the true start; ``s`` about 1 with
  ``flow_scale_sigma``, the paper's 5 % blood-velocity error (:data:`FLOW_SCALE_SIGMA`).  A wider prior lowers
  the bound.  The bound is Bayesian: it bounds the error averaged over this prior and the frame noise, so
  an estimator that happened to know ``s`` better than 5 % is not covered (the shipped observers' model has
  the blood velocity 5 % off, one prior sigma).
* **Frames.** Exactly the run's: each frame delivered at tick ``k`` (``meas_t_acq_s`` finite) measures the
  true position at its acquisition tick with independent Gaussian noise ``sigma`` per axis
  (``imager.noise_sigma_m``).  The aberrant frames (``meas_outlier``) are known to be aberrant and dropped;
  an estimator that must detect them has no more information.  Frames the imager never delivered (dropped,
  or superseded by a newer one due at the same tick) carry none.
* **Causality and latency.** The bound at tick ``k`` uses the frames delivered by ``t_k`` (after the
  observer's update at ``t_k``, as ``x_hat`` is recorded): a frame is fused at its acquisition tick and its
  information carried to the tick of delivery and on (the imager's sequence and latency, as they were).
* **Linearisation.** The transition from tick ``k`` to ``k + 1`` is ``Phi_k = expm(A_k dt)``, ``A_k`` the
  Jacobian of ``(Xd, F, 0)`` in ``(X, Xd, s)`` averaged over the tick's two ends **along the recorded true
  trajectory of the run** (forward differences of ``F``).  The information recursion
  ``J_{k+1} = Phi_k^{-T} J_k Phi_k^{-1}`` (``+ H^T R^-1 H`` at a frame) is run in its covariance form, the
  Kalman filter of the linearised plant (for a linear-Gaussian model the PCRB is that filter's covariance).
  The bound is therefore exact for the plant linearised along the trajectory; for the nonlinear plant it is
  the usual linearised PCRB, which the property test (test/unit/analysis/test_estimation_bound.py) checks
  against every shipped observer over 100 seeds.
* **Walls.** The bound knows nothing of the vessel's wall.  An estimator that does (the EKF's
  ``wall_projection: lumen``) has information the bound lacks while the bead is at a wall, and can beat it
  there; and through the contact and the steep surface forces the linearised plant is not the plant.  So the
  comparison window (``mask`` of :class:`RunBound`) leaves out every tick at which the bead's surface is
  within ``wall_band_radii`` bead radii of a wall (``-delta_m < wall_band_radii * r``; default one radius, the
  EKF's constraint zone :data:`~vesselbot_ros.control.ekf_observer.CONSTRAINT_ZONE_RADII`) and the
  ``wall_memory_s`` (0.1 s) after each such tick (the time a constrained estimate's extra knowledge of the
  wall-normal position takes to fade on the wall-attracted axis, whose growth rate is 5-20 1/s).  Beyond the
  band the constraint "the bead is in the lumen" is a radius or more away, tens of the bound's standard
  deviations (10-15 um): it tells an estimator near the bound nothing.  The bound holds on the window, not on
  the excluded ticks (``RunBound.excluded_fraction``: 0 in the shipped networks, about 0.1 in the straight
  vessel, whose reference runs half a millimetre from the wall).

The bound's ``rms_m`` is ``sqrt(mean over the window of trace(P_pos))``; over seeds, the root of the mean of
the seeds' mean squares, set against the observers' ``sqrt(mean of squared rms)`` on the same windows.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.compiled_stage import model_f_into
from vesselbot_ros.control.ekf_observer import s_inverse
from vesselbot_ros.control.model import BLOOD_VELOCITY_ERROR, DynamicsModel
from vesselbot_ros.physics.integrator import new_workspace
from vesselbot_ros.physics.kernel import I_V_F
from vesselbot_ros.sim.scenario import Scenario
from vesselbot_ros.vessels.tree_field import vessel_geom

__all__ = ["FLOW_SCALE_SIGMA", "jacobians", "RunBound", "EstimationBound", "transitions", "frames_of", "bound_variance",
           "run_bound", "estimation_bound", "expm_batch", "wall_mask"]

#: The prior sigma of the unknown flow scale ``s``: the paper's 5 % blood-velocity error.
FLOW_SCALE_SIGMA = BLOOD_VELOCITY_ERROR


def jacobians(plant: DynamicsModel, ts: npt.NDArray[np.float64], p: npt.NDArray[np.float64],
               v: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """(n, 2d+1, 2d+1) Jacobians of ``(Xd, F, 0)`` in ``(X, Xd, s)`` at every tick (forward differences of ``F``:
    10 nm, 0.1 um/s and 1e-6 in ``s``, far below the wall's and the flow's scales).

    One compiled call over the ticks (:func:`_jacobians_kernel`): the same ``F`` as :meth:`DynamicsModel.F`
    (memoryless contact), the same bits as calling it tick by tick (test_estimation_bound), where a Python loop
    of ``2 d + 2`` calls a tick took five sixths of a bound's time."""
    d = plant.dims
    scaled = plant.p.copy()
    scaled[I_V_F] = plant.p[I_V_F] * (1.0 + 1e-6)
    _work, fbuf, sc = new_workspace(d)
    out = np.zeros((len(ts), 2 * d + 1, 2 * d + 1))
    _jacobians_kernel(np.ascontiguousarray(ts, dtype=np.float64), np.ascontiguousarray(p, dtype=np.float64),
                      np.ascontiguousarray(v, dtype=np.float64), plant.geom, vessel_geom(scaled, plant.packed),
                      np.zeros(4), fbuf, sc, np.zeros(2 * d), np.zeros(d), out)
    return out


@numba.njit(cache=True, nogil=True)
def _jacobians_kernel(ts, p, v, geom, geom_s, free, fbuf, sc, y, g0, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`jacobians` into ``out`` (n, 2d+1, 2d+1), zeros on entry; ``geom_s``: ``geom`` with the flow scaled by
    ``1 + 1e-6``."""
    n, d = p.shape
    x = np.empty(d)
    z = np.empty(d)
    f0 = np.empty(d)
    f1 = np.empty(d)
    for k in range(n):
        t = ts[k]
        for c in range(d):
            x[c] = p[k, c]
            z[c] = v[k, c]
            out[k, c, d + c] = 1.0
        model_f_into(t, x, z, geom, free, fbuf, sc, y, g0, f0)
        for j in range(d):
            xj = x[j]
            x[j] = xj + 1e-8
            model_f_into(t, x, z, geom, free, fbuf, sc, y, g0, f1)
            x[j] = xj
            for c in range(d):
                out[k, d + c, j] = (f1[c] - f0[c]) / 1e-8
            zj = z[j]
            z[j] = zj + 1e-7
            model_f_into(t, x, z, geom, free, fbuf, sc, y, g0, f1)
            z[j] = zj
            for c in range(d):
                out[k, d + c, d + j] = (f1[c] - f0[c]) / 1e-7
        model_f_into(t, x, z, geom_s, free, fbuf, sc, y, g0, f1)
        for c in range(d):
            out[k, d + c, 2 * d] = (f1[c] - f0[c]) / 1e-6


def transitions(scenario: Scenario, timeseries: Mapping[str, Any]) -> npt.NDArray[np.float64]:
    """(n, 2d+1, 2d+1) transitions ``Phi_k`` from tick ``k`` to ``k + 1`` of ``(X, Xd, s)``, linearised along the
    run's true trajectory (``p_true``, ``v_true``; module docstring); the last one is the identity."""
    plant = DynamicsModel(scenario.physics, scenario.sim.integrator)
    ts = np.asarray(timeseries["t_s"], dtype=np.float64)
    jac = jacobians(plant, ts, np.asarray(timeseries["p_true"]), np.asarray(timeseries["v_true"]))
    dt = np.diff(ts)
    phi = np.empty_like(jac)
    phi[:-1] = expm_batch(0.5 * (jac[:-1] + jac[1:]) * dt[:, None, None])
    phi[-1] = np.eye(jac.shape[1])
    return phi


def expm_batch(a: npt.NDArray[np.float64], order: int = 12) -> npt.NDArray[np.float64]:
    """``expm`` of each of the (n, m, m) matrices ``a``, at once: scaling and squaring of a Taylor polynomial.

    ``scipy.linalg.expm`` takes a batch too, but runs its Pade path one matrix at a time (0.3 ms for the
    7x7 transitions of a tick, whose norm is 5-20 from the drag and the image-charge attraction: half a second
    per run); here every matrix is scaled by the same ``2^-s`` to a 1-norm <= 1/2, where the order-12 Taylor
    polynomial's truncation is below 1e-13 relative, then squared ``s`` times, in batched ``matmul``
    (test_estimation_bound checks it against scipy's).
    """
    a = np.asarray(a, dtype=np.float64)
    norm = float(np.max(np.sum(np.abs(a), axis=-2))) if a.size else 0.0
    s = max(0, int(math.ceil(math.log2(norm / 0.5)))) if norm > 0.5 else 0
    x = a / 2.0 ** s
    eye = np.broadcast_to(np.eye(a.shape[-1]), a.shape)
    out = eye + x / order
    for k in range(order - 1, 0, -1):  # Horner: I + x/1 (I + x/2 (I + ...))
        out = eye + np.matmul(x, out) / k
    for _ in range(s):
        out = np.matmul(out, out)
    return out


def frames_of(timeseries: Mapping[str, Any]) -> list[tuple[int, int]]:
    """(delivery tick, acquisition tick) of every frame the run's observer got that was not aberrant."""
    ts = np.asarray(timeseries["t_s"], dtype=np.float64)
    t_acq = np.asarray(timeseries["meas_t_acq_s"], dtype=np.float64)
    outlier = np.asarray(timeseries["meas_outlier"], dtype=bool)
    out = []
    for k in np.flatnonzero(np.isfinite(t_acq) & ~outlier):
        j = int(np.searchsorted(ts, t_acq[k] - 1e-9))  # the acquisition tick (the imager acquires on ticks)
        out.append((int(k), min(j, int(k))))
    return out


def bound_variance(phi: npt.NDArray[np.float64], frames: list[tuple[int, int]], sigma_m: float,
                   prior_sd: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """(n,) PCRB on the mean-square position error at every tick, given the frames delivered by then.

    Args:
        phi: (n, m, m) transitions (:func:`transitions`), ``m = 2 d + 1``.
        frames: (delivery tick, acquisition tick) of each frame to fuse, in delivery order (:func:`frames_of`).
        sigma_m: The frames' noise per axis (m).
        prior_sd: (m,) prior standard deviations of ``(X, Xd, s)`` at tick 0.
    """
    fr = np.asarray(frames, dtype=np.int64).reshape(-1, 2)
    p0 = np.diag(np.asarray(prior_sd, dtype=np.float64) ** 2)
    return np.asarray(_bound_kernel(np.ascontiguousarray(phi, dtype=np.float64), np.ascontiguousarray(fr[:, 0]),
                                    np.ascontiguousarray(fr[:, 1]), float(sigma_m) ** 2, p0))


@numba.njit(cache=True)
def _propagate(phi, p, tmp):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``p <- phi p phi^T`` in place (``tmp``: (m, m) scratch)."""
    m = p.shape[0]
    for i in range(m):
        for j in range(m):
            acc = 0.0
            for k in range(m):
                acc += phi[i, k] * p[k, j]
            tmp[i, j] = acc
    for i in range(m):
        for j in range(m):
            acc = 0.0
            for k in range(m):
                acc += tmp[i, k] * phi[j, k]
            p[i, j] = acc


@numba.njit(cache=True)
def _bound_kernel(phi, deliver, acquire, r2, p0):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`bound_variance`'s recursion (a frame fused at its acquisition tick, its information carried to the tick
    of delivery and on): the covariance form of the information recursion, the Kalman update with ``H = [I_d 0]``
    symmetrised, in loops over the (m, m) matrices (a Python loop of numpy products took ~30 ms a run)."""
    n, m, _ = phi.shape
    d = (m - 1) // 2
    out = np.empty(n)
    tmp = np.empty((m, m))
    s_inv = np.empty((d, d))
    gain = np.empty((m, d))  # K = P H^T (H P H^T + R)^-1, every entry written at each frame
    p_acq = p0.copy()
    p_now = p0.copy()
    k_acq = 0
    fi = 0
    nf = deliver.shape[0]
    for k in range(n):
        fused = False
        while fi < nf and deliver[fi] == k:  # fuse at its acquisition tick
            j = min(k, max(k_acq, acquire[fi]))
            fi += 1
            for i in range(k_acq, j):
                _propagate(phi[i], p_acq, tmp)
            k_acq = j
            s_inverse(p_acq, r2, d, s_inv)  # the filter's (H P H^T + R)^-1, d = 2 or 3
            for i in range(m):  # K
                for a in range(d):
                    acc = 0.0
                    for c in range(d):
                        acc += p_acq[i, c] * s_inv[c, a]
                    gain[i, a] = acc
            for i in range(m):  # P - K H P
                for jj in range(m):
                    acc = 0.0
                    for a in range(d):
                        acc += gain[i, a] * p_acq[a, jj]
                    tmp[i, jj] = p_acq[i, jj] - acc
            for i in range(m):
                for jj in range(m):
                    p_acq[i, jj] = 0.5 * (tmp[i, jj] + tmp[jj, i])
            fused = True
        if fused:  # the newest frame's information brought to now
            p_now[:, :] = p_acq
            for i in range(k_acq, k):
                _propagate(phi[i], p_now, tmp)
        tr = 0.0
        for a in range(d):
            tr += p_now[a, a]
        out[k] = tr
        _propagate(phi[k], p_now, tmp)  # to the next tick
    return out


@dataclasses.dataclass(frozen=True)
class RunBound:
    """The bound of one run, against the observer that flew it.

    Attributes:
        variance_m2: (n,) PCRB on the mean-square position error at every tick.
        mask: (n,) the comparison window: ``t >= sim.metrics_after_s`` and away from the walls (module docstring).
        observer_sq_m2: (n,) the run's observer's squared position error ``||x_hat - p_true||^2``.
        bound_rms_m: ``sqrt(mean(variance_m2[mask]))`` (NaN if the window is empty).
        observer_rms_m: ``sqrt(mean(observer_sq_m2[mask]))``.
        excluded_fraction: The share of the metrics window left out for the walls.
    """

    variance_m2: npt.NDArray[np.float64]
    mask: npt.NDArray[np.bool_]
    observer_sq_m2: npt.NDArray[np.float64]
    bound_rms_m: float
    observer_rms_m: float
    excluded_fraction: float


def _prior_sd(d: int, position_m: float, velocity_m_per_s: float, flow_scale_sigma: float) -> npt.NDArray[np.float64]:
    return np.array([position_m] * d + [velocity_m_per_s] * d + [flow_scale_sigma], dtype=np.float64)


def wall_mask(scenario: Scenario, timeseries: Mapping[str, Any], wall_band_radii: float,
              wall_memory_s: float) -> npt.NDArray[np.bool_]:
    """(n,) True at ticks away from the walls: the bead's surface more than ``wall_band_radii`` radii from every
    wall, and no such tick in the ``wall_memory_s`` before."""
    ts = np.asarray(timeseries["t_s"], dtype=np.float64)
    gap = -np.asarray(timeseries["delta_m"], dtype=np.float64)
    near = ~(gap > wall_band_radii * scenario.physics.robot.radius_m)
    if not near.any():
        return np.ones(len(ts), dtype=bool)
    last = np.full(len(ts), -np.inf)  # time of the latest near tick at or before each tick
    idx = np.where(near, np.arange(len(ts)), -1)
    idx = np.maximum.accumulate(idx)
    last[idx >= 0] = ts[idx[idx >= 0]]
    return np.asarray(ts - last > wall_memory_s + 1e-12)


def run_bound(scenario: Scenario, timeseries: Mapping[str, Any], *, sigma_scale: float = 1.0,
              flow_scale_sigma: float = FLOW_SCALE_SIGMA, prior_position_sigma_m: float = 1e-3,
              prior_velocity_sigma_m_per_s: float = 1e-2, wall_band_radii: float = 1.0,
              wall_memory_s: float = 0.1, phi: npt.NDArray[np.float64] | None = None) -> RunBound:
    """The PCRB of one run (module docstring) and its observer's error on the same window.

    Args:
        scenario: The scenario the run flew (its true physics, imager noise and metrics window).
        timeseries: The run's time series (``t_s``, ``p_true``, ``v_true``, ``delta_m``, ``meas_t_acq_s``,
            ``meas_outlier``, ``x_hat``).
        sigma_scale: Multiplies the frames' noise (1: the imager's; > 1 weakens the bound into one that is
            no bound, for showing the comparison can fail).
        flow_scale_sigma, prior_position_sigma_m, prior_velocity_sigma_m_per_s: The prior (module docstring).
        wall_band_radii, wall_memory_s: The walls' exclusion from the comparison window (module docstring).
        phi: The run's :func:`transitions`, if already computed.
    """
    phi = transitions(scenario, timeseries) if phi is None else phi
    d = (phi.shape[1] - 1) // 2
    var = bound_variance(phi, frames_of(timeseries), scenario.imager.noise_sigma_m * sigma_scale,
                         _prior_sd(d, prior_position_sigma_m, prior_velocity_sigma_m_per_s, flow_scale_sigma))
    ts = np.asarray(timeseries["t_s"], dtype=np.float64)
    after = ts >= scenario.sim.metrics_after_s - 1e-12
    mask = after & wall_mask(scenario, timeseries, wall_band_radii, wall_memory_s)
    err = np.asarray(timeseries["x_hat"], dtype=np.float64) - np.asarray(timeseries["p_true"], dtype=np.float64)
    sq = np.sum(err * err, axis=1)
    ok = mask & np.isfinite(sq)
    return RunBound(var, mask, sq, math.sqrt(np.mean(var[ok])) if ok.any() else math.nan,
                    math.sqrt(np.mean(sq[ok])) if ok.any() else math.nan,
                    1.0 - float(np.count_nonzero(mask)) / max(1, int(np.count_nonzero(after))))


@dataclasses.dataclass(frozen=True)
class EstimationBound:
    """:func:`estimation_bound` over seeds.

    Attributes:
        seeds: The seeds, in order.
        bound_rms_m: The bound over the seeds' windows: ``sqrt(mean over seeds of bound_rms^2)``.
        observer_rms_m: The observer's error on the same windows: ``sqrt(mean over seeds of observer_rms^2)``.
        per_seed_bound_m, per_seed_observer_m: Each seed's ``RunBound.bound_rms_m`` / ``observer_rms_m``.
        excluded_fraction: The mean share of the metrics window left out for the walls.
    """

    seeds: tuple[int, ...]
    bound_rms_m: float
    observer_rms_m: float
    per_seed_bound_m: tuple[float, ...]
    per_seed_observer_m: tuple[float, ...]
    excluded_fraction: float


def _combine(vals: Iterable[float]) -> float:
    a = np.array([v for v in vals if math.isfinite(v)], dtype=np.float64)
    return math.sqrt(float(np.mean(a * a))) if a.size else math.nan


def estimation_bound(scenario: Scenario, seeds: Iterable[int], **kwargs: Any) -> EstimationBound:
    """Run the scenario's closed loop on each seed and bound its position estimation error (:func:`run_bound`;
    ``kwargs`` go there): the bound holds for every causal estimator fed that run's frames, on its trajectory.

    Raises:
        ModelInputError, ConfigError: the run fails (as :func:`~vesselbot_ros.sim.closed_loop.run_closed_loop`).
    """
    from vesselbot_ros.sim.closed_loop import run_closed_loop  # deferred: the loop's compiled kernels

    seeds = tuple(int(s) for s in seeds)
    runs = [run_bound(scenario, run_closed_loop(scenario, s).timeseries, **kwargs) for s in seeds]
    b = tuple(r.bound_rms_m for r in runs)
    o = tuple(r.observer_rms_m for r in runs)
    return EstimationBound(seeds, _combine(b), _combine(o), b, o,
                           float(np.mean([r.excluded_fraction for r in runs])) if runs else math.nan)
