"""Coplanar moves within each station leave the side of the laser plane open, station by
station. Many stations: the two-step keeps the sides that agree on one rotation, where
trying every combination is out of reach (2^20). Starts that fit nearly alike through
the nominal poses: the joint model decides by their likelihoods, and refuses only when
it cannot tell, saying by how much they differ. Known answers from the simulator with
the arm's geometry off its model."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.estimation import solve
from spherecal.estimation.options import kinematic_effects
from spherecal.estimation.refine import NoiseAssumptions, cost_at, refine
from spherecal.estimation.starts import settle_alternative_starts
from spherecal.motion.kinematic_plan import plan_kinematic_stations
from spherecal.plugins.host import PluginHost
from spherecal.report.assess import verdict
from spherecal.sim import RobotErrorModel, simulate_dataset, standard_cell
from reference_sensor import reference_fov
from test_kinematic_model import NOISE, OPTIONS, planned_config

KINEMATIC = OPTIONS.model_copy(update={"identify_kinematics": True})


@pytest.fixture(scope="module")
def kin():
    return PluginHost().arm_kinematics({"type": "abb_irb2400"})


@pytest.fixture(scope="module")
def coplanar(kin, tmp_path_factory):
    """The kinematic planner's 20 eye-in-hand stations, each swept along two parallel
    straight lines (no wander: the moves of a station are coplanar), on an arm off its
    nominal geometry: the cell and the dataset."""
    sweep = _plan(planned_config(tmp_path_factory.mktemp("plan"), "eye_in_hand"), kin).sweep
    cell = standard_cell("eye_in_hand", seed=1, noise=NOISE, robot_error=RobotErrorModel(), arm=kin,
                         fov=reference_fov())
    lines = [simulate_dataset(cell, sweep.model_copy(update={"lateral_amplitude_mm": 0.0, "profiles_per_station": 4,
                                                             "station_offsets_mm": [offset]}))
             for offset in [(0.0, 0.0), (6.0, -6.0)]]
    obs = [o.model_copy(update={"index": i}) for i, o in enumerate(lines[0].observations + lines[1].observations)]
    return cell, lines[0].model_copy(update={"observations": obs})


def test_coplanar_sweeps_at_twenty_stations_are_solved_without_a_nominal(kin, coplanar):
    """Twenty stations of coplanar moves, no nominal transform, a kinematic calibration:
    solved, within 3 standard deviations of the true transform, not RED; a handful of
    sign choices tried (those whose stations agree), not the first 256 of 2^20 (whose
    best was half a turn off)."""
    cell, ds = coplanar
    sol = solve(ds, KINEMATIC, kinematics=kin)
    ts = sol.two_step
    assert set(ts.diagnostics["station_move_rank"].values()) == {2}
    assert ts.diagnostics["sign_combinations_tried"] <= 40
    X = cell.true_transform
    e = geo.rotvec_from_matrix(sol.refined.R @ X.rotation_matrix.T)
    assert np.all(np.abs(e) < 3 * np.sqrt(np.diag(sol.refined.covariance)[:3])), np.degrees(e)
    assert geo.rotation_angle_deg(ts.R, X.rotation_matrix) < 0.5
    assert verdict(sol.result).level != "red"


def test_starts_that_fit_alike_are_decided_by_the_joint_likelihood(kin, coplanar):
    """Given the right start and a rival: a rival 1.4 deg off leads the joint model to the
    same solution (one answer, nothing to refuse); a rival half a turn about the sensor's
    z leads it to another solution, which it rejects by a likelihood ratio far above
    1000:1. Either way the solution kept is the true one."""
    cell, ds = coplanar
    sol = solve(ds, KINEMATIC, kinematics=kin)
    ts, problem = sol.two_step, sol.problem
    noise = NoiseAssumptions(sol.result.diagnostics.noise["point_noise_mm"], KINEMATIC.pose_translation_noise_mm,
                             KINEMATIC.pose_rotation_noise_deg)
    effects = {"station_effects": None, "kinematic_effects": kinematic_effects(KINEMATIC, kin.chain)}

    def refit(p, start):
        return refine(p, start.R, start.t, start.centre, noise, False, True, **effects)

    def cost(ref, scale):
        return cost_at(problem, ref, noise, False, scale, **effects)

    X = cell.true_transform
    rivals = {"1.4 deg": geo.matrix_from_rotvec(np.radians([1.0, -1.0, 0.0])) @ ts.R,
              "half a turn": ts.R @ geo.matrix_from_rotvec([0.0, 0.0, np.pi])}
    for name, R in rivals.items():
        rival = dataclasses.replace(ts, R=R, alternatives=[], diagnostics={})
        said = []
        chosen_ts, chosen = settle_alternative_starts(problem, dataclasses.replace(ts, alternatives=[rival]), refit,
                                                      cost, said.append)
        choice = chosen_ts.diagnostics["joint_model_choice"]
        assert choice["starts_refined"] == 2
        assert geo.rotation_angle_deg(chosen.R, X.rotation_matrix) < 0.1
        if name == "1.4 deg":
            assert choice["distinct_solutions"] == 1 and choice["neg2_log_likelihood_margin"] is None
        else:
            assert choice["distinct_solutions"] == 2 and choice["neg2_log_likelihood_margin"] > 1e3
            assert said[-1].startswith("the joint model prefers one of them by a -2 log-likelihood margin of")


def _plan(cfg, kin):
    """The kinematic planner's stations for the configuration ``cfg``, on the arm ``kin``."""
    return plan_kinematic_stations(cfg.acquisition, cfg.calibration, cfg.mounting, cfg.nominal_transform, cfg.sphere,
                                   kin)
