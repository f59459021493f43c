"""Configuration of the ABB IRB 2400 plugin (the ``robot`` section when ``type =
"abb_irb2400"``). Lengths in mm, angles in degrees, times in seconds."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

from spherecal.plugins import (BASE_DIR_CONTEXT_KEY, InputError, LineLinkSettings, Pose,
                               Vec3)
from spherecal.plugins import SimulatedControllerSettings as CoreSimulatedControllerSettings
from spherecal.plugins import WorkspaceBox as CoreWorkspaceBox

from .kinematics import Irb2400Geometry, Irb2400Kinematics, calibrated_kinematics_for, kinematics_for



class WorkspaceBox(CoreWorkspaceBox):
    """Axis-aligned box in the base frame (mm) the flange origin must stay in. Moves
    whose target lies outside are refused before anything is sent. Defaults: the IRB
    2400's reach."""

    min_mm: Vec3 = Field((-1600.0, -1600.0, 0.0), description="lower corner (x, y, z) in base, mm")
    max_mm: Vec3 = Field((1600.0, 1600.0, 2000.0), description="upper corner (x, y, z) in base, mm")


class EgmSettings(BaseModel):
    """Pose streaming over Externally Guided Motion (EGM, IRC5 option 689-1): the
    controller sends ``EgmRobot`` messages over UDP to this PC while ordinary moves run
    (read-only: no EGM motion control). The controller side is ``SpherecalEgm.mod`` and a
    UDPUC transmission protocol whose remote address and port are this PC's
    (docs/robot-abb-irb2400.md, "Pose streaming")."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    port: int = Field(
        6510, ge=0, le=65535, description="the UDP port this PC listens on: the remote port of the controller's "
        "UDPUC transmission protocol; 0 takes any free port (simulated runs and tests only: a real controller sends "
        "to the port its configuration names)",
    )
    address: str = Field(
        "0.0.0.0", min_length=1, description="the local address to listen on (0.0.0.0: every interface; or the "
        "address of the PC's port on the robot's network)",
    )
    sample_period_ms: int = Field(
        4, ge=4, le=100, description="the controller's sample period, ms (EGMStreamStart \\SampleRate): a multiple "
        "of 4",
    )
    stall_timeout_s: float = Field(
        0.25, gt=0, le=10, description="no sample for this long while the stream is on ends the stream "
        "(PoseStreamStalled), keeping what was received",
    )
    first_sample_timeout_s: float = Field(
        2.0, gt=0, le=30, description="after the start command, wait this long for the first sample before "
        "refusing (the UDPUC device's remote address and port, a firewall)",
    )
    clock_jump_tolerance_ms: float = Field(
        2.0, gt=0, le=1000, description="a stamp that differs by more than this from the previous one plus the "
        "sequence numbers' periods is a clock jump (PoseStreamClockError); a stamp that does not increase always "
        "is",
    )
    receive_buffer_bytes: int = Field(
        4 * 1024 * 1024, ge=64 * 1024, le=256 * 1024 * 1024, description="the UDP socket's receive buffer asked "
        "for, bytes (the system may grant less: net.core.rmem_max on Linux)",
    )

    @field_validator("sample_period_ms")
    @classmethod
    def _multiple_of_4(cls, v: int) -> int:
        if v % 4:
            raise ValueError(f"must be a multiple of 4 ms (the controller samples every 4 ms), got {v}")
        return v


class ProgrammedLineSettings(BaseModel):
    """Pose streaming without EGM (an S4C+, an IRC5 without the option): the poses are
    computed on the PC along the programmed line of each move, not measured. The
    controller (``SpherecalLine.mod``) stamps each move where its path passes
    ``stamp_distance_mm`` from its start (past the acceleration ramp) and when it is in
    position at its end, with its own clock; the flange is taken to follow the straight
    line at the move's speed, timed from that stamp, with a trapezoidal speed profile of
    ``acceleration_mm_s2`` at both ends (which only the ramps depend on). The arm's path
    error at speed and any difference from that profile are in the poses, so in the
    result's error: the result says so (docs/robot-abb-irb2400.md, "Programmed-line
    poses")."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    mode: Literal["programmed_line"] = Field(
        description="programmed_line: poses along each move's programmed line, timed by the controller's stamps "
        "of its start and end (the only mode here; EGM streaming is configured in [robot.egm])",
    )
    sample_period_ms: int = Field(
        4, ge=1, le=100, description="the computed stream's sample period, ms of the controller's clock",
    )
    stamp_distance_mm: float = Field(
        10.0, ge=0, le=500, description="the start stamp is taken where the path passes this distance from its "
        "start, mm (TriggInt \\Start): past the acceleration ramp (at least speed^2 / acceleration_mm_s2, so "
        "that an acceleration off by a third still leaves it on the constant-speed part), the constant-speed "
        "poses do not depend on the acceleration assumed. A move whose ramp reaches it has every sample marked "
        "on_ramp",
    )
    acceleration_mm_s2: float = Field(
        2000.0, gt=0, le=100_000, description="path acceleration and deceleration assumed at both ends of every "
        "move, mm/s^2 (a trapezoidal speed profile): an assumption, not a controller figure (ABB's profiles are "
        "jerk-limited and depend on the load and the pose); where it is wrong, the poses near the ramps are",
    )
    ramp_margin_s: float = Field(
        0.05, ge=0, le=2, description="samples within this time of a speed ramp assumed (and the ramps "
        "themselves) are marked on_ramp: a solve leaves out the profiles there, where a wrong acceleration "
        "moves the computed pose most; 0 marks the ramps alone",
    )
    path_error_mm: float = Field(
        0.1, ge=0, le=100, description="the arm's path error at constant speed assumed, mm (how far the flange "
        "may be from the programmed line): stated with the result, never checked here",
    )
    duration_tolerance_s: float = Field(
        0.02, gt=0, le=5, description="a move whose two stamps along the path lie further apart in time than the "
        "programmed speed puts them, by more than this, s (or whose time from the second to in position is "
        "shorter than the profile assumed, or longer by more than settle_max_s), did not follow the programmed "
        "line (a speed override below 100 %, a stop): its stream ends with an error",
    )
    settle_max_s: float = Field(
        0.5, ge=0, le=10, description="the most a fine point may take to be in position after the motion, s",
    )

    def assumption(self) -> str:
        """What the computed poses assume, for the stream and the result."""
        from spherecal.plugins import PROGRAMMED_LINE_ASSUMPTION  # (the streams' model: loaded when streaming)

        return (f"{PROGRAMMED_LINE_ASSUMPTION} (timed from a stamp {self.stamp_distance_mm:g} mm along each move; "
                f"trapezoidal speed, {self.acceleration_mm_s2:g} mm/s^2 assumed on the ramps, marked +-"
                f"{self.ramp_margin_s:g} s; path error at speed assumed within {self.path_error_mm:g} mm)")


class SimulatedLineSettings(BaseModel):
    """The simulated controller's stamps of the programmed-line stream (simulated runs):
    its clock and when its start stamp is taken. The simulated arm moves with
    ``simulated.acceleration_mm_s2``, which may differ from the acceleration the PC
    assumes (``pose_stream.acceleration_mm_s2``)."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    clock_drift_ppm: float = Field(
        -25.0, ge=-1000, le=1000, description="the controller clock's rate minus one, parts per million",
    )
    start_latency_s: float = Field(
        0.012, ge=-0.1, le=0.5, description="the start stamp is taken this long after the path passes the stamp's "
        "distance, s (the trap routine's latency; negative: the arm lags the interpolated path by more than that)",
    )
    start_jitter_s: float = Field(
        0.001, ge=0, le=0.05, description="standard deviation of the start stamp about its latency, s",
    )
    seed: int | None = Field(None, description="seed of the jitter (None: the controller's seed)")


class SimulatedEgmSettings(BaseModel):
    """The simulated controller's EGM stream (simulated runs): its own clock, its stamp
    jitter and its losses."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    clock_epoch_s: float = Field(
        1.7e9, ge=0, description="the controller's clock at simulated time zero, s (EgmClock counts from 1970)",
    )
    clock_drift_ppm: float = Field(
        30.0, ge=-1000, le=1000, description="the controller clock's rate minus one, parts per million",
    )
    stamp_jitter_s: float = Field(
        20e-6, ge=0, le=0.004, description="standard deviation of each stamp about the true sample instant, s "
        "(stamps carry microseconds)",
    )
    drop_probability: float = Field(
        0.0, ge=0, lt=1, description="probability that a sample is lost on its way (one at a time)",
    )
    first_seqno: int = Field(0, ge=0, lt=2**32, description="the first message's sequence number (uint32)")
    seed: int | None = Field(None, description="seed of the jitter and the losses (None: the controller's seed)")


class SimulatedControllerSettings(CoreSimulatedControllerSettings):
    """The simulated controller used when the run is simulated (a SimulatedCell is
    given): it serves the same protocol over a real link on localhost (the
    core's settings, :class:`spherecal.plugins.SimulatedControllerSettings`, with
    the IRB 2400's home joints and its RAPID server's links)."""

    transport: Literal["tcp", "pty", "socket"] = Field(
        "tcp",
        description="the link the simulated controller serves: tcp: the serial server's line carried over TCP "
        "on 127.0.0.1 (socket://); pty: a pseudo-terminal device (POSIX only); socket: the RAPID socket server "
        "of an IRC5 (SpherecalSocket.mod) on 127.0.0.1 (socket://), whose every new connection is a new "
        "session that forgets the staged target",
    )
    single_precision: bool = Field(
        True, description="round reported values to 32-bit floats, as RAPID num does"
    )
    home_joints_deg: tuple[float, float, float, float, float, float] = Field(
        (0.0, 0.0, 0.0, 0.0, 90.0, 0.0), description="joints at start-up, controller convention, deg"
    )
    base_frame: Pose | None = Field(
        None, description="the controller's base frame, world_from_base (translation_mm, quaternion_wxyz w first), "
        "as a riser, an inverted mount or a multi-robot cell configures it: GETP reports tool0 in wobj0 (world) and "
        "TGT targets are taken in world; None: base = world. For tests of the check on connect",
    )
    egm: SimulatedEgmSettings = Field(
        default_factory=SimulatedEgmSettings, description="the simulated EGM pose stream (used when robot.egm is set)",
    )
    line: SimulatedLineSettings = Field(
        default_factory=SimulatedLineSettings, description="the simulated controller's move stamps (used when "
        "robot.pose_stream.mode is programmed_line)",
    )


class AbbIrb2400Config(LineLinkSettings):
    """ABB IRB 2400 on an IRC5 or S4C+ controller running ``SpherecalServer.mod`` with a link
    module, talking the spherecal line protocol over a serial line (``SpherecalSerial.mod``)
    or, on an IRC5, over TCP (``SpherecalSocket.mod``; see docs/robot-abb-irb2400.md). The
    link and motion settings are the core's (:class:`spherecal.plugins.LineLinkSettings`,
    which also checks a ``socket://host:port`` port)."""

    port: str = Field(
        "/dev/ttyS0",
        description="the link to the controller: a serial device (/dev/ttyS0, /dev/ttyUSB0, COM1) or another "
        "pyserial URL (rfc2217://...) for SpherecalSerial.mod, or socket://host:port for the IRC5 socket server "
        "SpherecalSocket.mod (its SERVER_ADDRESS and SERVER_PORT); ignored in simulated runs",
    )

    serial_number: str | None = Field(
        None, max_length=100, description="the robot's serial number (its nameplate), for the report and the "
        "result's provenance; the controller protocol does not report it"
    )
    pose_source: Literal["controller", "joints"] = Field(
        "controller",
        description="flange pose from the controller (GETP, CRobT tool0/wobj0) or from the joint "
        "readings (GETJ) through this plugin's forward kinematics",
    )
    orientation_speed_deg_s: float = Field(
        100.0, gt=0, le=500, description="largest reorientation speed a move asks for (speeddata v_ori), deg/s; "
        "each move asks for less when its sensor (the tool point) would otherwise exceed the move's speed"
    )
    workspace: WorkspaceBox = Field(default_factory=WorkspaceBox, description="allowed flange positions, base, mm")
    base_frame_tolerance_mm: float = Field(
        5.0, gt=0, le=100, description="on connect, the controller's pose of tool0 in wobj0 (world) may differ from "
        "this plugin's forward kinematics of the reported joints (base) by this much, mm; more means a base frame "
        "is configured and the connection is refused (an Absolute Accuracy controller differs by up to about 2 mm)",
    )
    base_frame_tolerance_deg: float = Field(
        0.5, gt=0, le=10, description="the same check's limit on the orientation difference, deg",
    )
    j23_coupled: bool = Field(
        True,
        description="the controller reports axis 3 relative to the horizontal (parallel linkage; "
        "true for the IRB 2400): q3_model = q3_controller - q2_controller",
    )
    geometry: Irb2400Geometry = Field(
        default_factory=Irb2400Geometry, description="kinematic geometry (defaults: published IRB 2400 values)"
    )
    simulated: SimulatedControllerSettings = Field(
        default_factory=SimulatedControllerSettings, description="the simulated controller of simulated runs"
    )
    egm: EgmSettings | None = Field(
        None, description="pose streaming over Externally Guided Motion (IRC5 with option 689-1 and "
        "SpherecalEgm.mod): start_pose_stream / stop_pose_stream; None: the robot does not stream",
    )
    pose_stream: ProgrammedLineSettings | None = Field(
        None, description="pose streaming without EGM (an S4C+): poses computed along each move's programmed "
        "line, timed by the controller's stamps (SpherecalLine.mod); None: no such stream. Not with robot.egm",
    )
    calibrated_model: Path | None = Field(
        None,
        description="calibrated geometry of this arm: a URDF file (metres; joints joint_1..joint_6 in the serial "
        "model's convention, q3_model = q3_controller - q2_controller when j23_coupled; links base_link and "
        "tool0), such as the robot_calibrated.urdf of a kinematic calibration. Applied on the PC side: targets "
        "are sent as the nominal pose of the joints that reach them on the calibrated model, and flange poses "
        "come from the joint readings through it. A relative path resolves against the configuration file's "
        "folder when the host is given it, else the working directory",
    )

    @field_validator("calibrated_model", mode="after")
    @classmethod
    def _resolve_model(cls, v: Path | None, info: ValidationInfo):
        if v is None:
            return None
        v = Path(v).expanduser()
        base = (info.context or {}).get(BASE_DIR_CONTEXT_KEY)
        if not v.is_absolute():
            v = Path(base) / v if base is not None else v
        v = v.resolve()
        if "geometry" in info.data and "j23_coupled" in info.data:  # else they failed: reported there
            try:
                calibrated_kinematics_for(info.data["geometry"], info.data["j23_coupled"], v)
            except InputError as exc:
                raise ValueError(str(exc)) from None
        return v

    @model_validator(mode="after")
    def _check_pose_stream(self):
        if self.pose_stream is None:
            return self
        if self.egm is not None:
            raise ValueError(
                "robot.pose_stream (programmed_line) and robot.egm are both set: a controller with EGM streams its "
                "measured pose (keep [robot.egm]); one without computes it from the programmed line (keep "
                "[robot.pose_stream]); give one")
        if self.calibrated_model is not None:
            raise ValueError(
                "robot.pose_stream (programmed_line) cannot go with a calibrated_model: the controller moves along "
                "its nominal model's line, which the calibrated arm does not follow; leave one of them out")
        return self

    @model_validator(mode="after")
    def _check_calibrated_model(self):
        if self.calibrated_model is None:
            return self
        if "pose_source" in self.model_fields_set and self.pose_source == "controller":
            raise ValueError(
                "pose_source = 'controller' cannot go with a calibrated_model: the controller reports its "
                "nominal model's pose; with a calibrated model the flange pose comes from the joint readings "
                "(leave pose_source out, or set it to 'joints')"
            )
        return self

    def kinematics(self) -> Irb2400Kinematics:
        """The arm's kinematics as configured: the calibrated model's
        (:class:`~.kinematics.CalibratedIrb2400Kinematics`) when ``calibrated_model`` is
        set, else the nominal geometry's."""
        if self.calibrated_model is not None:
            return calibrated_kinematics_for(self.geometry, self.j23_coupled, self.calibrated_model)
        return kinematics_for(self.geometry, self.j23_coupled)
