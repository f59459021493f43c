"""The settings of the simulated robot controller (:mod:`spherecal.sim.controller`), in a
module of their own: a robot plugin's configuration model includes them, and describing
a plugin (``spherecal plugins``, every ``solve``) should not load the controller's server
or the simulated cell."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from spherecal.core.models import Pose


class SimulatedControllerSettings(BaseModel):
    """The simulated controller used when the run is simulated (a SimulatedCell is
    given): it serves the line protocol over a real link on localhost."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    transport: Literal["tcp", "pty", "socket"] = Field(
        "tcp",
        description="the link the simulated controller serves: tcp: a serial server's line carried over TCP on "
        "127.0.0.1 (socket://); pty: a pseudo-terminal device (POSIX only); socket: a controller's socket server "
        "on 127.0.0.1 (socket://), whose every new connection is a new session that forgets the staged target",
    )
    pose_noise: Literal["cell", "settings"] = Field(
        "cell",
        description="GETP noise: 'cell' uses the SimulatedCell's pose noise (cell.report_pose); "
        "'settings' uses pose_translation_noise_mm and pose_rotation_noise_deg below",
    )
    pose_translation_noise_mm: float = Field(0.0, ge=0, le=100, description="GETP position noise, SD per base axis, mm")
    pose_rotation_noise_deg: float = Field(0.0, ge=0, le=10, description="GETP orientation noise, SD about each base axis, deg")
    joint_noise_deg: float = Field(0.0, ge=0, le=10, description="GETJ noise, SD per joint, deg")
    single_precision: bool = Field(
        True, description="round reported values to 32-bit floats, as many controllers' number types do"
    )
    motion_time_scale: float = Field(
        0.0, ge=0, le=100, description="a move also waits this factor times its duration (distance / speed or "
        "angle / reorientation speed, the longer) in real time, s (0: no real waiting; every move takes its "
        "simulated time on the cell's clock whatever this is)"
    )
    acceleration_mm_s2: float = Field(
        2000.0, gt=0, le=100_000, description="path acceleration and deceleration of every move in simulated time, "
        "mm/s^2 (an assumption for an IRB 2400-class arm: 2 m/s^2)")
    settle_s: float = Field(0.2, ge=0, le=60, description="simulated standstill at the end of every move before "
                            "the controller answers (a fine point's settling), s")
    max_controller_speed_mm_s: float = Field(7000.0, gt=0, le=100_000,
                                             description="the controller's own TCP speed limit, mm/s")
    home_joints_deg: tuple[float, ...] | None = Field(
        None, description="joints at start-up, controller convention, deg (None: the arm's home when its robot type "
        "declares one, else all zero)"
    )
    seed: int | None = Field(0, ge=0, le=2**63 - 1, description="seed of the simulator's noise generator (None: random)")
    base_frame: Pose | None = Field(
        None, description="the controller's base frame, world_from_base (translation_mm, quaternion_wxyz w first), "
        "as a riser, an inverted mount or a multi-robot cell configures it: GETP reports the flange in the world "
        "frame and TGT targets are taken in it; None: base = world. For tests of the check on connect",
    )
