"""The input mapping (vesselbot_ros.scanner.input_mapping): U = B G, with tau_m or as printed."""

from __future__ import annotations

import numpy as np

from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.scanner.input_mapping import input_matrix


def test_input_mapping_tau_m() -> None:
    phys = PhysicsParams()
    rho = 0.8 * 7874 + 0.2 * 1500
    b = input_matrix(phys, "with_tau_m")
    np.testing.assert_allclose(b, 0.8 * 1.72e6 / rho * np.eye(2), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(input_matrix(phys, "paper_printed"), 1.72e6 / rho * np.eye(2), rtol=1e-12, atol=1e-9)
