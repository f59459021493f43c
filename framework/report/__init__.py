"""Reports and exports of calibration results."""
