"""vesselbot_ros.bag."""
