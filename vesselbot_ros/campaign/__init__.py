"""Campaigns: Monte-Carlo runs and parameter sweeps of the pure closed loop on Dask (``vesselbot campaign``)."""
