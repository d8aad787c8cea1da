"""vesselbot_ros.physics."""
