"""Simulated multi-robot worlds."""
