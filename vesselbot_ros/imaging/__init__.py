"""MR data of the bead synthesised from physics, and the default tracker (pure core: numpy, scipy, numba; no ROS).

* :mod:`~vesselbot_ros.imaging.dipole`: the bead's field perturbation (a magnetised sphere's dipole) and the
  frame convention (B0 along the bore, the project's x axis);
* :mod:`~vesselbot_ros.imaging.acquisition`: a 2-D gradient-echo slice and MS-SET-style 1-D projections,
  with their parameters (:class:`~vesselbot_ros.imaging.acquisition.MrImagingParams`) and presets;
* :mod:`~vesselbot_ros.imaging.tracker`: the default tracker (the bead's position from one frame, or a
  rejection reason);
* :mod:`~vesselbot_ros.imaging.bounds`: the Cramer-Rao bound of the position under the same image model;
* :mod:`~vesselbot_ros.imaging.imager_stage`: the loop's stages, the ``mr_images`` imager (frames timed by the
  sequence, :mod:`~vesselbot_ros.imaging.frames`) and the ``dipole_fit`` tracker (their parameters:
  :mod:`~vesselbot_ros.imaging.imager_params`).

See docs/imaging.md.
"""
