"""ament_python package vesselbot_ros (works with plain pip and with colcon)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "vesselbot_ros"

NODES = {
    "vesselbot_plant": "plant_node",
    "vesselbot_imager": "imager_node",
    "vesselbot_observer": "observer_node",
    "vesselbot_controller": "controller_node",
    "vesselbot_coil_driver": "coil_driver_node",
    "vesselbot_reference": "reference_node",
    "vesselbot_recorder": "recorder_node",
}

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    package_data={PACKAGE: ["physics/data/*"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
    ],
    install_requires=["setuptools", "numpy", "scipy", "numba", "PyYAML", "matplotlib", "rosbags", "mcap", "mcap-ros2-support", "dask", "distributed", "pyarrow"],
    zip_safe=False,
    maintainer="vesselbot maintainers",
    maintainer_email="maintainers@vesselbot.example",
    description="ROS 2 emulator of MRI-guided magnetic microrobot navigation (Arcese et al., IEEE TBME 2012)",
    license="Apache-2.0",
    entry_points={
        "console_scripts": ["vesselbot = vesselbot_ros.cli:main"]
        + [f"{exe} = {PACKAGE}.nodes.{mod}:main" for exe, mod in NODES.items()],
    },
)
