"""What a worker of a cluster is asked before any task: standard library only.

The functions here travel to the workers by value (``cluster.check_workers`` registers this
module with cloudpickle), so a worker without obstacle_detection still runs them and says so,
instead of dying when it unpickles a task.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.metadata
import os
import pathlib
import sys
from collections.abc import Sequence

PACKAGE = 'obstacle_detection'


def package_facts() -> dict[str, str]:
    """Return the package this process imports: version, source digest, folder; or ``error``."""
    try:
        package = importlib.import_module(PACKAGE)
    except Exception as err:   # noqa: BLE001 - the reason goes back to the client
        return {'error': f'{type(err).__name__}: {err}'}
    root = pathlib.Path(package.__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob('*.py')):
        digest.update(path.relative_to(root).as_posix().encode() + b'\0' + path.read_bytes())
    try:
        version = importlib.metadata.version(PACKAGE)
    except importlib.metadata.PackageNotFoundError:
        version = 'unknown'
    return {'version': version, 'digest': digest.hexdigest()[:12], 'where': str(root)}


def missing_paths(paths: Sequence[str]) -> list[str]:
    """Return those of ``paths`` that do not exist in this process's view of the files."""
    return [path for path in paths if not os.path.exists(path)]


def _travel_by_value() -> None:
    """Have cloudpickle (Dask's) send this module's functions by value, not by name."""
    try:
        import cloudpickle
    except ImportError:   # no Dask: nothing travels
        return
    cloudpickle.register_pickle_by_value(sys.modules[__name__])


_travel_by_value()
