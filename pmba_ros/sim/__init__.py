"""Deterministic simulated scenes, sequences and front-end bags."""
