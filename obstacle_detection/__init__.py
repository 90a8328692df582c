"""Obstacle detection from depth images (seed thesis chapter 4): pipeline, conversions, node."""
