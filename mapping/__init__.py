"""Mapping front end: RGB-D frames and segmentation masks -> object maps."""
