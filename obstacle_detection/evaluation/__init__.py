"""Evaluation: what the scores count (:mod:`.metrics`), suite runners, video scores, datasets.

The pipeline never imports this package.
"""

from pathlib import Path


class EvaluationError(ValueError):
    """Input the evaluation cannot use: the ``problem``, the ``path`` it is in when known.

    ``usage=True``: an unknown scenario, parameter or metric name (the tools exit 2).
    """

    def __init__(self, problem: str, path: str | Path | None = None, *,
                 usage: bool = False) -> None:
        super().__init__(problem if path is None else f'{path}: {problem}')
        self.path = None if path is None else Path(path)
        self.problem = problem
        self.usage = usage
