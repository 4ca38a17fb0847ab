"""Trajectory evaluation: formats, alignment, ATE and RPE."""
