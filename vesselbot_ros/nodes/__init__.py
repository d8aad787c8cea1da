"""vesselbot_ros.nodes."""
