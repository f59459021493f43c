"""Files at the edges: datasets, stream recordings and ROS 2 bags in, results, PLY point
clouds, the run log, safe writes and the exporters' contract. Imports :mod:`spherecal.core`
only."""
