"""``vesselbot design-map``'s figure (vesselbot_ros.analysis.design_map_cli): bounded before any map is computed."""

from __future__ import annotations

import pytest
import yaml

from vesselbot_ros.analysis.design_map_cli import MAX_FIGURE_PIXELS, check_figure
from vesselbot_ros.cli import main
from vesselbot_ros.config import ConfigError


def test_a_figure_taller_than_matplotlib_draws_is_refused_before_the_maps(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    """200 vessels: a 1320 x 70466 pixel figure, which Agg cannot draw (the old command computed the 600 maps first
    and ended in matplotlib's traceback)."""
    vessels = [{"name": f"v{i}", "diameter_m": 1e-3, "velocity_m_per_s": 0.02} for i in range(200)]
    path = tmp_path / "study.yaml"
    path.write_text(yaml.safe_dump({"design_study": {"vessels": vessels, "grid": {"n_lambda": 2, "n_delta": 2}}}))
    assert main(["design-map", "--study-config", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and ("design_study.vessels=200 vessels: the figure would be 1320 x 70466 pixels, more than "
                              f"matplotlib's {MAX_FIGURE_PIXELS} along a side: list at most 185 vessels or use --no-png") in err[0]
    assert not (tmp_path / "o").exists()
    check_figure(185)
    with pytest.raises(ConfigError, match="design_study.vessels=186 vessels"):
        check_figure(186)
