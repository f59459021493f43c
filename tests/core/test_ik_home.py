"""Where inverse kinematics starts when the arm's joints are not known: an arm whose zero
joints stretch its elbow (a singularity) is reached from its declared home, or, declaring
none, from the spread seeds after zero; the simulated cell, simulate_dataset and the
kinematic planner never seed at zero joints when a home is declared; a numerical solve
that fails says it did not converge from its seed, and only a pose beyond the arm's reach
is called out of reach."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from spherecal.core.errors import InputError, PluginError
from spherecal.core.kinematics import (ArmWithHome, SerialChain, declared_home_joints_deg, ik_seeds_deg,
                                       joints_from_home)
from spherecal.core.models import Pose
from spherecal.core.urdf import IkNotConverged, chain_to_urdf
from spherecal.core.workspace import WorkspaceBox
from spherecal.plugins import hookimpl
from spherecal.plugins.host import PluginHost
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov

#: A KR 6 R900-class arm (mm) whose forearm is in line with the upper arm at zero joints:
#: the elbow is stretched there, a singularity.
HOME_DEG = [0.0, -60.0, 90.0, 0.0, 45.0, 0.0]
#: A pose the arm reaches with its elbow bent (these joints); from zero joints the solver
#: finds the other elbow branch, with the wrist beyond its limit.
BENT_DEG = [10.0, -60.0, 80.0, 5.0, 40.0, 0.0]


def _placement(x=0.0, z=0.0, R=None) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = [x, 0.0, z]
    if R is not None:
        T[:3, :3] = R
    return T


@pytest.fixture(scope="module")
def stretched_urdf(tmp_path_factory) -> str:
    placements = np.array([_placement(z=400.0), _placement(x=25.0), _placement(x=455.0), _placement(),
                           _placement(x=420.0), _placement(x=80.0)])
    axes = np.array([[0, 0, -1], [0, 1, 0], [0, 1, 0], [-1, 0, 0], [0, 1, 0], [-1, 0, 0]], dtype=float)
    tool0 = _placement(R=np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]))  # z along the flange's x
    limits = np.radians([[-170, 170], [-190, 45], [-120, 156], [-185, 185], [-120, 120], [-350, 350]])
    path = tmp_path_factory.mktemp("urdf") / "stretched.urdf"
    path.write_text(chain_to_urdf(SerialChain(placements, axes, tool0), "stretched", joint_limits_rad=limits))
    return str(path)


def _arm(urdf: str, **extra):
    return PluginHost().arm_kinematics({"type": "urdf", "urdf": urdf, **extra})


def test_zero_joints_are_a_singular_seed_and_the_message_says_so(stretched_urdf):
    arm = _arm(stretched_urdf)
    pose = arm.flange_pose_from_joints(BENT_DEG)
    with pytest.raises(IkNotConverged, match=r"from joints \[0.0, 0.0, 0.0, 0.0, 0.0, 0.0\] deg found only a "
                                             r"solution beyond a joint limit \(the flange lies [\d.]+ mm from the "
                                             r"shoulder, within the arm's reach") as err:
        arm.joints_from_flange_pose(pose, np.zeros(6))
    assert "out of reach" not in str(err.value) and "robot.home_joints_deg" in str(err.value)
    # a pose truly beyond reach is still called so
    with pytest.raises(InputError, match=r"is out of reach of the arm .* mm from the shoulder, which reaches"):
        arm.joints_from_flange_pose(Pose.from_rt(np.eye(3), [1500.0, 0.0, 400.0]), HOME_DEG)


def test_the_configured_home_seeds_inverse_kinematics(stretched_urdf):
    arm = _arm(stretched_urdf, home_joints_deg=HOME_DEG)
    np.testing.assert_array_equal(declared_home_joints_deg(arm), HOME_DEG)
    assert np.array_equal(ik_seeds_deg(arm)[0], HOME_DEG)
    pose = arm.flange_pose_from_joints(BENT_DEG)
    np.testing.assert_allclose(arm.joints_from_flange_pose(pose), BENT_DEG, atol=1e-6)  # no seed: the home
    np.testing.assert_allclose(joints_from_home(arm, pose), BENT_DEG, atol=1e-6)


def test_an_arm_without_a_home_is_reached_from_the_spread_seeds(stretched_urdf):
    arm = _arm(stretched_urdf)
    assert declared_home_joints_deg(arm) is None and np.array_equal(ik_seeds_deg(arm)[0], np.zeros(6))
    pose = arm.flange_pose_from_joints(BENT_DEG)
    joints = joints_from_home(arm, pose)  # a solution within the limits, not necessarily the nearest one
    np.testing.assert_allclose(arm.flange_matrix_from_joints(joints), pose.as_matrix(), atol=1e-8)
    with pytest.raises(InputError, match=r"out of reach .* \(nor from 4 other seeds spread over the joints\)"):
        joints_from_home(arm, Pose.from_rt(np.eye(3), [1500.0, 0.0, 400.0]))


@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
@pytest.mark.parametrize("home", [HOME_DEG, None])
def test_simulated_data_on_an_arm_stretched_at_zero(stretched_urdf, mounting, home):
    """The simulated cell laid out for the arm and simulate_dataset's first target (which
    zero joints did not reach: 'out of reach ... choose a pose closer to the robot')."""
    arm = _arm(stretched_urdf, **({} if home is None else {"home_joints_deg": home}))
    cell = standard_cell(mounting, seed=0, arm=arm, fov=reference_fov())
    ds = simulate_dataset(cell, SweepPlan())
    assert len(ds.observations) == 40
    if home is not None:  # the elbow bent as at home, all along
        assert all(obs.joints_deg[2] > 30.0 for obs in ds.observations)


class _SeedRecorder(ArmWithHome):
    """An arm that notes the seed of every inverse kinematics call."""

    def __init__(self, arm, home):
        super().__init__(arm, home)
        self.seeds = []

    def joints_from_flange_pose(self, base_from_flange, seed_joints_deg=None):
        self.seeds.append(None if seed_joints_deg is None else np.asarray(seed_joints_deg, dtype=float).copy())
        return self._arm.joints_from_flange_pose(base_from_flange, seed_joints_deg)


def test_the_kinematic_planner_and_its_check_start_from_the_home():
    from spherecal.config import AcquisitionConfig, CalibrationOptions, KinematicPlanSettings, SphereConfig, \
        TransformConfig
    from spherecal.motion.acquisition import plan_targets
    from spherecal.motion.kinematic_plan import check_plan_identifies_kinematics, plan_kinematic_stations
    from spherecal.motion.planning import with_standoff

    host = PluginHost()
    arm = _SeedRecorder(host.arm_kinematics({"type": "abb_irb2400"}), [0.0, 10.0, -10.0, 0.0, 60.0, 0.0])
    cell = standard_cell("eye_in_hand", seed=0, fov=reference_fov())
    acq = AcquisitionConfig(sphere_centre_mm=tuple(cell.sphere_centre_mm),
                            workspace=WorkspaceBox(min_mm=(0.0, -800.0, 0.0), max_mm=(1600.0, 800.0, 1600.0)),
                            sweep=with_standoff(SweepPlan(), reference_fov()),
                            kinematic_plan=KinematicPlanSettings(stations=6, candidates=24))
    nominal = TransformConfig(translation_mm=tuple(cell.true_transform.translation),
                              quaternion_wxyz=tuple(cell.true_transform.quaternion_wxyz))
    sphere, options = SphereConfig(radius_mm=cell.sphere_radius_mm), CalibrationOptions(identify_kinematics=True)
    plan = plan_kinematic_stations(acq, options, "eye_in_hand", nominal, sphere, arm)
    assert arm.seeds[0] is not None and np.array_equal(arm.seeds[0], arm.home_joints_deg)
    assert all(s is not None and np.any(s) for s in arm.seeds)  # never from zero joints
    arm.seeds.clear()
    targets = plan_targets(acq, "eye_in_hand", nominal, sphere, plan.sweep)
    check_plan_identifies_kinematics(targets, acq, options, "eye_in_hand", nominal, sphere, arm, plan)
    assert np.array_equal(arm.seeds[0], arm.home_joints_deg)


def test_a_robot_type_declares_its_home_through_the_host():
    host = PluginHost()
    abb = host.arm_kinematics({"type": "abb_irb2400"})
    np.testing.assert_array_equal(declared_home_joints_deg(abb), [0.0, 0.0, 0.0, 0.0, 90.0, 0.0])
    # a home from the configuration, or a wrong one (the plugin's error, naming it)
    rtype = host.registry.robot_type("abb_irb2400")

    class Plugin:
        @hookimpl
        def spherecal_register_devices(self, registry):
            registry.add_robot(dataclasses.replace(rtype, name="abb_from_config",
                                                   home_joints_deg=lambda config: (0.0, 5.0, 5.0, 0.0, 80.0, 0.0)))
            registry.add_robot(dataclasses.replace(rtype, name="abb_bad_home", home_joints_deg=(0.0, 0.0, 0.0)))

    host = PluginHost([("home_test", Plugin())], load_entry_points=False)
    np.testing.assert_array_equal(declared_home_joints_deg(host.arm_kinematics({"type": "abb_from_config"})),
                                  [0.0, 5.0, 5.0, 0.0, 80.0, 0.0])
    with pytest.raises(PluginError, match=r"plugin 'home_test': robot type 'abb_bad_home' declares "
                                          r"home_joints_deg: expected 6 finite joint values"):
        host.arm_kinematics({"type": "abb_bad_home"})


def test_the_simulated_controller_starts_at_the_declared_home(stretched_urdf):
    from spherecal.sim.controller import SimulatedController

    arm = _arm(stretched_urdf, home_joints_deg=HOME_DEG)
    np.testing.assert_array_equal(SimulatedController(arm, n_joints=6).joints_deg, HOME_DEG)
    np.testing.assert_array_equal(SimulatedController(_arm(stretched_urdf), n_joints=6).joints_deg, np.zeros(6))
