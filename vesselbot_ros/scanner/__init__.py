"""The MRI system as the loop sees it (pure core): the imager (tracking frames), the gradient coil and its limits,
the input mapping ``U = B G``, the imaging/propulsion sequence and the hardware presets."""
