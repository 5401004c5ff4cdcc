"""Orchestration: a problem from input files to output files (``solve``), many problems on
Dask (``batch``). The command line is a thin layer over these functions."""
