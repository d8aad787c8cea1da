"""ament_python package vesselbot_ros (works with plain pip and with colcon)."""

import importlib.util
import sys
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "vesselbot_ros"


def _graph_spec():
    """The graph spec (stdlib only), loaded by path: the console scripts derive from its roles."""
    path = Path(__file__).resolve().parent / PACKAGE / "graph_spec.py"
    spec = importlib.util.spec_from_file_location("_vesselbot_graph_spec", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    package_data={PACKAGE: ["physics/data/*", "fastdds_profile.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        # the shipped scenarios, parameter sets, campaigns and the Foxglove layout: `vesselbot run --config NAME`
        # finds them here when installed (vesselbot_ros.config.shipped_config_dir)
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/config/campaigns", glob("config/campaigns/*.yaml")),
        (f"share/{PACKAGE}/config/campaigns/plans", glob("config/campaigns/plans/*.yaml")),
        (f"share/{PACKAGE}/config/campaigns/targets", glob("config/campaigns/targets/*.yaml")),
        (f"share/{PACKAGE}/config/plans", glob("config/plans/*.yaml")),
        (f"share/{PACKAGE}/config/vessels", glob("config/vessels/*.yaml")),
        # the sampled CFD fields of the shipped networks (vesselbot_ros.vessels.cfd, "Shipped fields")
        (f"share/{PACKAGE}/config/cfd", glob("config/cfd/*.npz")),
        (f"share/{PACKAGE}/config/foxglove", glob("config/foxglove/*.json")),
    ],
    install_requires=["setuptools", "numpy", "scipy", "numba", "PyYAML", "matplotlib", "rosbags", "mcap", "mcap-ros2-support", "dask", "distributed", "pyarrow", "foxglove-sdk", "tqdm", "gymnasium"],
    # optional: a learned baseline on the environments (tools/train_ppo.py); the same pins as requirements-learn.txt
    extras_require={"learn": ["stable-baselines3==2.9.2", "torch==2.13.0"]},
    zip_safe=False,
    maintainer="vesselbot maintainers",
    maintainer_email="maintainers@vesselbot.example",
    description="ROS 2 emulator of MRI-guided magnetic microrobot navigation (Arcese et al., IEEE TBME 2012)",
    license="Apache-2.0",
    entry_points={
        "console_scripts": _graph_spec().console_scripts(),
    },
)
