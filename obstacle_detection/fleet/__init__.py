"""Offline work at scale: bags, sweeps and evaluations on a Dask cluster (docs/fleet.md)."""
