"""The frames of a ROS 2 bag's recording (docs/conventions.md, "A ROS 2 bag's frames"):
how the calibrated sensor frame lies in the clouds' frame, and the frame ids the bag
names, as a result's :class:`~spherecal.core.models.DataFrames`.

A profile's points lie in the sensor frame's x = 0 plane (docs/conventions.md,
"Frames"). A driver that puts the laser line along its cloud's y (the default,
``line_axis="y"``) publishes in that frame itself. One that puts it along x
(``line_axis="x"``) publishes in a frame turned about z: the reader takes a cloud point
(x, 0, z) as the profile point (y, z) = (x, z), so ``sensor_from_cloud = Rz(+90 deg)``
(y_sensor = x_cloud, x_sensor = -y_cloud): the sensor frame's axes are the cloud
frame's turned by -90 degrees about z (x_sensor along -y_cloud, y_sensor along x_cloud).
"""

from __future__ import annotations

import numpy as np

from spherecal.core.models import DataFrames, Pose

#: ``sensor_from_cloud`` in words, for each line axis whose cloud frame is not the sensor frame.
SENSOR_FROM_CLOUD_TEXT = {"x": "Rz(+90 deg): y_sensor = x_cloud, x_sensor = -y_cloud"}

_RZ_PLUS_90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def sensor_from_cloud(line_axis: str) -> Pose:
    """The pose of the clouds' frame in the calibrated sensor frame for clouds whose laser
    line runs along ``line_axis`` ("y": the identity; "x": Rz(+90 deg))."""
    if line_axis == "y":
        return Pose.identity()
    if line_axis == "x":
        return Pose.from_rt(_RZ_PLUS_90, np.zeros(3))
    raise ValueError(f"line_axis must be 'y' or 'x', got {line_axis!r}")


def bag_frames(provenance: dict) -> DataFrames | None:
    """The frames a recording converted from a ROS 2 bag names (its provenance, written by
    :func:`spherecal.io.rosbag.read_bag`), or None for a recording of another source."""
    if provenance.get("source") != "rosbag2":
        return None
    line_axis = provenance.get("line_axis", "y")

    def frame(*keys):
        value = next((provenance[k] for k in keys if provenance.get(k)), None)
        return value.lstrip("/") if isinstance(value, str) and value.strip("/") else None

    return DataFrames(
        source="rosbag2",
        base_frame_id=frame("base_frame_id"),
        flange_frame_id=frame("flange_frame_id"),
        # (recordings converted before the key was named for the cloud call it sensor_frame_id)
        cloud_frame_id=frame("cloud_frame_id", "sensor_frame_id"),
        sensor_from_cloud=sensor_from_cloud(line_axis),
        sensor_from_cloud_text=SENSOR_FROM_CLOUD_TEXT.get(line_axis),
    )
