"""Blender probes and oracles run by the tests (python -m ...); not shipped in the wheel."""
