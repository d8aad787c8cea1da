"""vesselbot_ros.analysis."""
