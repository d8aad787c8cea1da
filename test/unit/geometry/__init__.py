"""Tests of vesselbot_ros.geometry (a package, so that its conftest.py is not the module `conftest` test/unit/bag/ imports from)."""
