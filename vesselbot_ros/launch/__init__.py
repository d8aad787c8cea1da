"""Launching the node graph: processes, composition, the `vesselbot run` command."""
