"""Loaders of recorded multi-robot data sets."""
