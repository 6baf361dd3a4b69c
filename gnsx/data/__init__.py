"""Datasets: gnsx's on-disk format, metadata, readers for the formats users hold, generation."""
