"""The keep-out check of a plan of targets: which targets and moves it names, with the gap
found, what to change, and the closest approach of a plan that keeps its distance."""

import numpy as np
import pytest

from spherecal.core.field_of_view import SensorBody
from spherecal.core.geometry import matrix_from_rotvec
from spherecal.core.keep_out import KeepOutGeometry
from spherecal.core.models import Pose
from spherecal.motion.acquisition import Target
from spherecal.motion.keep_out import MAX_LISTED, KeepOut, check_keep_out, keep_out_message

#: The sensor 150 mm out on the flange's z, its body 160-210 mm out; the sphere (radius 20)
#: at (0, 185, 0): where the body stands when the flange has turned -90 deg about base x.
GEOMETRY = KeepOutGeometry("eye_in_hand", Pose.from_rt(np.eye(3), [0.0, 0.0, 150.0]),
                           SensorBody(min_mm=(-20.0, -20.0, 10.0), max_mm=(20.0, 20.0, 60.0)),
                           (0.0, 185.0, 0.0), 20.0, 0.0, 0.0)


def _turned(deg: float, x_mm: float = 0.0) -> Pose:
    return Pose.from_rt(matrix_from_rotvec(np.radians([deg, 0.0, 0.0])), [x_mm, 0.0, 0.0])


def _targets(*stations):
    """Targets of stations given as (label, [pose, ...])."""
    out = []
    for label, poses in stations:
        out += [Target(len(out) + k, label, p, k == 0, 10.0) for k, p in enumerate(poses)]
    return out


KEEP_OUT = KeepOut(GEOMETRY, 5.0, "a test body", "move it away", "turn less")


def test_a_plan_that_keeps_its_distance():
    targets = _targets(("S1", [_turned(0.0), _turned(0.0, 5.0)]), ("S2", [_turned(-30.0), _turned(-30.0, 5.0)]))
    finding = check_keep_out(targets, KEEP_OUT)
    assert finding.problems == [] and finding.moves == 3
    # the nearest: S2, its body centre (0, 92.5, 160) from the sphere's (0, 185, 0)
    assert finding.closest.clearance_mm > 100
    assert finding.summary(KEEP_OUT).startswith("keep-out: the sensor's body stays ")
    assert "3 moves" in finding.summary(KEEP_OUT)
    # checked again from where the arm stands: one move more, and the line says why
    again = check_keep_out(targets, KEEP_OUT, start=_turned(0.0, -5.0))
    assert again.moves == 4 and again.poses > finding.poses
    assert again.summary(KEEP_OUT).startswith("keep-out, from where the arm stands (its first move too): the sensor's "
                                              "body stays ")


def test_a_move_that_swings_through_the_sphere_is_named():
    targets = _targets(("S1", [_turned(0.0), _turned(0.0, 5.0)]), ("S2", [_turned(-150.0), _turned(-150.0, 5.0)]))
    finding = check_keep_out(targets, KEEP_OUT)
    (line,) = finding.problems
    assert line.startswith("the move from target 1 (station S1) to target 2 (station S2), 60% of the way, flange at ")
    assert "the sensor's body overlaps the sphere by " in line
    message = keep_out_message("plan", finding, KEEP_OUT)
    assert message.startswith("the plan brings the sensor's body within keep_out.clearance_mm = 5 mm of the sphere "
                              "or its stand; nothing was moved:\n  the move from target 1")
    assert "On a move between targets: the straight move between them brings the sensor's body and the sphere " \
           "together on its way; turn less." in message
    assert "At a target" not in message and "(a test body)" in message


def test_targets_too_near_are_named_by_station_and_their_moves_left_to_them():
    """S2's first two targets put the body round the sphere (-90 deg: 40 mm deep, the
    body's x face 20 mm from the centre), its third 60 mm aside (20 mm clear): one line for
    the station, naming its worst target; the moves into and out of them are not listed again."""
    targets = _targets(("S1", [_turned(0.0)]), ("S2", [_turned(-90.0), _turned(-90.0, 3.0), _turned(-90.0, 60.0)]),
                       ("S3", [_turned(0.0, 80.0)]))
    finding = check_keep_out(targets, KEEP_OUT)
    assert len(finding.problems) == 1, finding.problems
    (line,) = finding.problems
    assert line.startswith("targets 1, 2 (2 of 3) of station S2, worst target 1, flange at [0.0, 0.0, 0.0] mm: "
                           "the sensor's body overlaps the sphere by 40.0 mm"), line
    message = keep_out_message("plan", finding, KEEP_OUT)
    assert "At a target: move it away." in message and "On a move" not in message


def test_the_first_move_from_where_the_arm_stands():
    targets = _targets(("S1", [_turned(0.0), _turned(0.0, 5.0)]))
    finding = check_keep_out(targets, KEEP_OUT, start=_turned(-150.0))
    (line,) = finding.problems
    assert line.startswith("the first move, from where the arm stands to target 0 (station S1), 40% of the way")
    assert "On the first move: jog the arm clear of the sphere" in keep_out_message("plan", finding, KEEP_OUT)
    assert check_keep_out(targets, KEEP_OUT, start=_turned(-30.0)).problems == []


def test_a_clearance_is_a_gap_not_only_an_overlap():
    """S2 at -75 deg: the body 7.9 mm from the sphere's surface, inside a 10 mm
    clearance, outside a 5 mm one."""
    targets = _targets(("S1", [_turned(0.0)]), ("S2", [_turned(-75.0)]))
    gap = check_keep_out(targets, KEEP_OUT).closest.clearance_mm
    assert 5.0 < gap < 10.0
    strict = KeepOut(GEOMETRY, 10.0, "a test body")
    (line,) = check_keep_out(targets, strict).problems
    assert line == f"target 1 (station S2), flange at [0.0, 0.0, 0.0] mm: the sensor's body comes within {gap:.1f} mm " \
                   "of the sphere"


def test_a_long_list_is_cut():
    stations = [(f"S{k}", [_turned(-90.0, 0.1 * k)]) for k in range(MAX_LISTED + 3)]
    message = keep_out_message("plan", check_keep_out(_targets(*stations), KEEP_OUT), KEEP_OUT)
    assert message.count("\n  target ") == MAX_LISTED and "\n  ... and 3 more\n" in message
