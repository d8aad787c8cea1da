"""The MRI scanner as the loop sees it: the imaging/propulsion sequence and its hardware limits (pure core)."""
