"""Experiments of `pcvfe evaluate`: grids of runs on Dask, result tables, the report."""
