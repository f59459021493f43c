"""The foundations: frames, poses, observations and results, kinematics, URDF,
mapping and metrology figures. Imports NumPy, SciPy and pydantic only, nothing of spherecal's
above it."""
