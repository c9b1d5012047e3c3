"""Conformance kits: pytest-ready checks a plug-in's author runs on what they add to gainfarm,
and gainfarm runs on its own built-ins (gainfarm.testing.objectives: an objective)."""
