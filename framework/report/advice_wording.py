"""What the advice says that depends on how the data were taken.

Stop-and-go data: every pose is read with the robot at a standstill, so a pose read at
the wrong moment is one read before the robot stopped, and poses that scatter call for
reading them after it settled. A *recording* (on the fly: a result with ``timing``):
both devices stream while the robot moves and each profile's pose is interpolated from
the pose stream at its exposure's robot time (docs/on-the-fly.md); the robot never stops
to be read. Its advice names what a recording can change instead: the streams' stamps
and losses, the clock relation, the sweeps; and what its data show by design (profiles
at a sweep's entry, exit or the sphere's edge, the arm's smooth path error shared by
profiles taken close in time) as expected, not as faults.

Text only: :mod:`spherecal.report.assess` builds the advice from it.
"""

from __future__ import annotations

import math

#: The causes of flagged observations by a needle in the flag's reason: (needle, likely
#: cause, what to do), the first match wins; the sensor's artefacts first, named in
#: place of the generic causes. Stop-and-go data.
FLAG_CAUSES = [
    ("profile is clipped", "profiles clipped at the edge of the sensor's field of view", "keep the sphere inside "
     "the field of view (acquisition.sweep); a sensor should leave out points beyond its range, not hold them"),
    ("coarsely quantised", "depths on a coarse grid", "report depths at the sensor's full resolution"),
    ("inconsistent", "pose read at the wrong moment or paired with the wrong profile",
     "read the pose only after the robot has stopped (RAPID: a fine point and WaitRob \\InPos before CRobT) "
     "and check that no reading was lost or repeated in the sequence"),
    ("points (needs", "the laser line barely touches the sphere",
     "move that station's sweep so the line crosses the sphere near its middle"),
    ("scatter about their circle", "the sensor's noise above the limit (exposure, a dull, dirty or wet sphere, "
     "ambient light), the sphere all the same",
     "check the sensor's exposure and the sphere's surface; if this is the noise the sensor gives, raise the "
     "calibration setting max_circle_rms_mm above it"),
    ("do not lie on a circle", "the profile is not the sphere (background, holder, reflections)",
     "check what the sensor sees at that pose; mask the background or move the sweep"),
    ("exceeds the sphere radius", "wrong sphere radius or a profile of something else",
     "check the certified radius in the dataset (mm) and what the sensor sees"),
    ("usable profiles", "too few usable profiles at that station",
     "add profiles to that station's sweep"),
    ("turned", "the robot turned within a station (only translations are allowed there)",
     "keep each station's orientation fixed during its sweep (linear moves, no reorientation); if the "
     "orientation readings are noisier than assumed, set calibration.pose_rotation_noise_deg"),
]

#: A recording's own causes, looked up before :data:`FLAG_CAUSES` (whose sensor artefacts
#: and sphere checks hold for a recording too).
RECORDING_FLAG_CAUSES = [
    *FLAG_CAUSES[:2],  # (the sensor's artefacts: named before the generic causes)
    # the screening's reason for a recording's profile near the sphere's edge says it is expected
    ("expected and left out", "profiles that cut the sphere near its edge, where the arm's error along the sweep "
     "shows many times larger", "a sweep on the fly crosses the whole sphere, so such profiles are expected: nothing "
     "to change unless they are many (then suspect the arm's path error along the sweeps or the clock relation)"),
    ("inconsistent", "a profile whose pose, interpolated from the pose stream at its time, is not where the arm was "
     "when it was exposed", "check that the sensor stamps each profile at its exposure (not at its arrival), that "
     "neither stream lost or repeated samples around it (each sweep's counts in the run's log) and the clock "
     "relation"),
    ("points (needs", "the laser line barely touching the sphere as a sweep enters or leaves it",
     "a sweep on the fly crosses the whole sphere, so a few are expected: nothing to change unless they are many"),
    ("in a gap of the pose stream", "no pose sample around the profile's time (a gap in the pose stream)",
     "no pose is guessed across a gap: nothing to change when they are few; many: the pose stream loses samples "
     "(its rate, the network, the PC's load)"),
    ("on a speed ramp", "profiles on a speed ramp of a computed pose stream, where the acceleration is assumed",
     "left out by design (robot poses not measured): nothing to change"),
    ("outside the pose stream's time span", "profiles exposed before the pose stream's first sample or after its "
     "last", "no pose is guessed beyond the stream: nothing to change when they are few; many: check that the pose "
     "stream runs throughout each sweep"),
]


def flag_cause(reason: str, recording: bool = False) -> tuple[str, str]:
    """(likely cause, what to do) of a flagged observation from its ``reason``; a
    ``recording``'s from :data:`RECORDING_FLAG_CAUSES` first."""
    for needle, cause, todo in (RECORDING_FLAG_CAUSES + FLAG_CAUSES if recording else FLAG_CAUSES):
        if needle in reason:
            return cause, todo
    return "see the reason given", "check that observation's profile and pose"


def recording_arm_calibration(seen: int, total: int) -> str:
    """What to do about the arm's geometric error after a recording: a kinematic calibration
    is taken stop-and-go (its planner's stations are refused on the fly), then measured
    through; ``seen`` of the arm's ``total`` geometric parameters these data see."""
    return ("calibrate the arm's geometry with spherecal in a stop-and-go run and measure through the calibrated "
            "model it writes (robot_calibrated.urdf): a kinematic calibration takes its stations stop-and-go, not "
            "on the fly ([acquisition] mode = \"stop_and_go\" with [calibration] identify_kinematics = true and no "
            "acquisition.sweep.tilts_deg: the planner chooses stations spread over the arm's joints and checks that "
            f"they identify it; this recording's data see {seen} of its {total} geometric parameters)")


#: Why a station of a recording is inconsistent with the robot's moves, and what to do.
RECORDING_STATION_CAUSE = (
    "On the fly the likely cause is a pose stream out of step with the profiles during that station's sweeps (lost "
    "or late samples or frames, a clock that stepped) or the arm's path error along them. Record that station's "
    "sweeps again, or drop it if the others suffice.")


def recording_pose_noise(pose_noise_mm: float, shots: float, repeatability_mm: float,
                         factor: float) -> tuple[str, str, str, str]:
    """(key, level, title, text) of the advice on a recording whose pose noise per profile,
    ``pose_noise_mm`` (per axis), exceeds ``factor`` x the robot's ``repeatability_mm``.
    ``shots``: how many consecutive profiles share the robot's error (the integrated
    autocorrelation of the residuals, ``diagnostics.refinement.time_correlation``); when
    the fit widened the noise per profile by its square root, the noise of one independent
    look is ``pose_noise_mm / sqrt(shots)``. Within ``factor`` x the repeatability that is
    the arm's smooth path error along the sweeps, said as such (green): the profiles come
    faster than it changes, not from a robot that repeats poorly."""
    from spherecal.estimation.on_the_fly import CORRELATED_SHOTS  # (recordings only: a dataset's solve lacks it)

    widened = shots > CORRELATED_SHOTS
    look_mm = pose_noise_mm / math.sqrt(shots) if widened else pose_noise_mm
    correlation = (f"the residuals are correlated in time over {shots:.1f} consecutive profiles (their integrated "
                   "autocorrelation, result.json diagnostics.refinement.time_correlation): the arm's smooth path error "
                   f"along a sweep, shared by the profiles taken within it, so the fit took the pose noise "
                   f"{math.sqrt(shots):.2f} times larger per profile for those profiles to weigh what their "
                   "independent looks weigh")
    if widened and look_mm <= factor * repeatability_mm:
        return ("pose_noise_time_correlated", "green", "The arm's path error is correlated along the sweeps",
                f"The fit's robot pose noise, {pose_noise_mm:.3f} mm per axis per profile, is above {factor:g} x the "
                f"repeatability {repeatability_mm} mm only because {correlation}. Per independent look it is about "
                f"{look_mm:.3f} mm, as the robot repeats. The stated uncertainty allows for it: nothing to change. "
                "More independent looks come from more sweeps (stations, directions, speeds), not from a higher "
                "profile rate.")
    shown = f" ({pose_noise_mm:.3f} mm per profile: {correlation})" if widened else ""
    return ("pose_noise_high", "amber", "Robot poses scatter more than the robot repeats",
            f"The data show a robot pose noise of about {look_mm:.3f} mm per axis{shown}, more than {factor:g} x "
            f"the repeatability {repeatability_mm} mm. On the fly each profile's pose is interpolated from the pose "
            "stream at its exposure: check the stream's resolution (at least 6 decimals of the quaternion; 3 "
            "decimals is about 0.1 deg), that its samples are the flange in the robot's base frame stamped when "
            "measured, and the clock relation; slower sweeps show less of the arm's path error at speed. Let the "
            "robot warm up. A wrong sphere radius looks the same: check it too.")
