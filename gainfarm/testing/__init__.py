"""Conformance kits for plug-in authors: pytest-ready checks, one module per plug-in group
(`gainfarm.testing.robots` for a robot)."""
