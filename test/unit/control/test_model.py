"""The dynamics model (vesselbot_ros.control.model) in a 3-D tree: F is the plant's kernel over the mass, B = b I,
and propagate integrates the plant's equations with the input as an acceleration; one class for every vessel."""

from __future__ import annotations

import numpy as np
import pytest

from vesselbot_ros.control.model import DynamicsModel
from vesselbot_ros.physics.integrator import new_workspace
from vesselbot_ros.physics.kernel import I_MASS
from vesselbot_ros.physics.tree_vessel import tree_forces_at
from vesselbot_ros.scanner.input_mapping import input_matrix
from vesselbot_ros.sim.plant import PlantSimulator
from vesselbot_ros.sim.scenario import load_scenario
from vesselbot_ros.vessels.tree_field import planar_twin

SCENARIO = "config/paper_iiic_network_upper_3d.yaml"


@pytest.fixture(scope="module")
def scenario():  # type: ignore[no-untyped-def]
    return load_scenario(SCENARIO)


def test_f_is_the_kernels_force_without_the_motive_one(scenario) -> None:  # type: ignore[no-untyped-def]
    m = DynamicsModel(scenario.model_physics(), scenario.sim.integrator)
    x, z = np.array([2e-3, 1e-4, 5e-4]), np.array([1e-3, -2e-4, 0.0])
    f = m.F(0.1, x, z)
    _w, fbuf, _sc = new_workspace(3)
    k = m.packed
    tree_forces_at(0.1, np.concatenate([x, z]), np.zeros(3), np.zeros(4), m.p, k.W, k.F, k.fh, fbuf)
    assert np.array_equal(f, fbuf[7] / m.p[I_MASS])
    assert not np.array_equal(m.F(0.1, x, z, 1.2), f)  # the flow scale reaches the blood velocity
    b = input_matrix(planar_twin(scenario.model_physics()))[0, 0]
    assert np.array_equal(m.input_matrix, b * np.eye(3))


def test_propagate_is_the_plant_under_the_same_push(scenario) -> None:  # type: ignore[no-untyped-def]
    phys = scenario.physics
    m = DynamicsModel(phys, scenario.sim.integrator)
    plant = PlantSimulator(phys, scenario.sim.integrator, 1e-3, [1e-3, 2e-4, 5e-4], [0.0, 0.0, 0.0])
    g = np.array([0.02, 0.01, 0.04])
    y = np.array([1e-3, 2e-4, 5e-4, 0.0, 0.0, 0.0])
    contact = m.new_contact_state()
    for k in range(50):
        m.propagate(k * 1e-3, (k + 1) * 1e-3, y, m.input_matrix @ g, contact)
        plant.step(g)
    assert np.allclose(y[:3], plant.state[:3], atol=1e-7, rtol=0)  # B G = tau V M G / m: rounding, then the step control
    assert m.stats[0] > 0


def test_the_plant_reports_its_wall_side_and_forces(scenario) -> None:  # type: ignore[no-untyped-def]
    plant = PlantSimulator(scenario.physics, scenario.sim.integrator, 1e-3, [2e-3, 0.0, 1.2e-3], [0.0, 0.0, 0.0])
    out = plant.output(with_forces=True)
    assert out.p.shape == (3,) and out.forces is not None and out.forces.shape == (8, 3)
    assert out.wall == 1.0 and -1.5e-3 < out.delta_m < 0.0  # the upper wall is the nearest, 0.05 mm away
    assert np.allclose(out.forces[7], out.forces[:7].sum(axis=0), rtol=1e-12, atol=0)
