"""vesselbot_ros.control."""
