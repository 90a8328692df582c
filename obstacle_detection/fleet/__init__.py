"""Offline work at scale: many bags, sweeps and evaluations on a Dask cluster (local by default).

``cluster`` opens the cluster (or none: this process) and runs tasks on it; ``bags`` runs
``bag_process`` over many bags, one task per bag; ``scoring`` spreads ``evaluate`` and
``sweep`` over the cluster, one task per (parameter point, sequence). Dask (``dask.distributed``)
is optional: without it everything runs in this process, with the same results.
"""
