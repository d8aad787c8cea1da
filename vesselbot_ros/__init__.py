"""vesselbot_ros: ROS 2 emulator of MRI-guided magnetic microrobot navigation.

The physics (:mod:`vesselbot_ros.physics`) and control
(:mod:`vesselbot_ros.control`) cores are pure numpy/scipy; the ROS 2 nodes in
:mod:`vesselbot_ros.nodes` are thin adapters around them.
"""

__version__ = "0.1.0"

from vesselbot_ros.numba_cache import ensure_fresh as _ensure_fresh_numba_cache

_ensure_fresh_numba_cache()
