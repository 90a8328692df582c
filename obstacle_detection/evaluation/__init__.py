"""Evaluation: what the scores count (:mod:`.metrics`), suite runners, video scores, datasets.

The pipeline never imports this package.
"""
