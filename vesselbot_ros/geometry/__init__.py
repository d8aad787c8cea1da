"""vesselbot_ros.geometry: the vessel wall geometry (planar polyline, 3-D surface, sampled field)."""
