"""vesselbot_ros.sim."""
