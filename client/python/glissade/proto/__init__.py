"""Stubs generated from proto/proto/glissade.proto when the package is built (setup.py)."""
