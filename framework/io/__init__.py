"""Files at the edges: datasets, results, PLY point clouds, the run log, safe writes and
the exporters' contract. Imports :mod:`spherecal.core` only."""
