"""The error to expect of a point measured at a new pose, with its budget.

A point p (sensor frame) measured at robot pose i lands in the frame the sphere is fixed
in (base in eye-in-hand, flange in eye-to-hand) at ``q = A_i X p`` (see :mod:`.problem`).
Its error there has four independent parts, each propagated to first order:

- the transform X and the sphere centre c, jointly: the error is that of q relative to
  where the calibration puts the same point of the scene (a point on the sphere: the
  fitted sphere), so X and c enter with their correlation, relative to the robot's frame
  (the common robot error excluded: it moves every pose alike, and the fitted sphere or
  transform with them);
- the robot's systematic error: with the station model, a new pose is a new draw of the
  station offset (per-axis ``s_rot``, ``s_trans`` as the fit estimated them from the
  inconsistency between stations); with the kinematic model, the arm's geometric error
  at the pose, less what the fitted transform and sphere absorbed of it (both move with
  the same parameters, so the part common to every pose cancels): the square of the
  estimated error plus its posterior variance;
- the robot's per-shot pose noise (as rescaled by the fit);
- the sensor's point noise (each of y and z).

Evaluated at the sensor-frame point where the sphere was seen (the mean of the used
profile points) and at every pose of the calibration, then averaged: "a new pose" means
one like the calibration's. The k = 2 figure is twice the RMS 3-D error, mm.
"""

from __future__ import annotations

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.models import StationPrediction
from spherecal.estimation.problem import Problem
from spherecal.estimation.refine import NoiseAssumptions, RefineResult, _pose_cov


def _jacobians(problem: Problem, R: np.ndarray, t: np.ndarray, p: np.ndarray):
    """d(q - c)/d(w, t, c) (n, 3, 9), dq/d(omega, tau) of the flange pose (n, 3, 6) and
    dq/dp (n, 3, 3)."""
    n = problem.n_profiles
    R0, t0 = problem.R0, problem.t0
    Rp = R @ p
    x = Rp + t  # the point in the frame X maps into (flange or base)
    JX = np.zeros((n, 3, 9))
    JX[:, :, 6:9] = -np.eye(3)  # relative to the fitted sphere centre
    JR = np.empty((n, 3, 6))
    if problem.mounting == "eye_in_hand":
        JX[:, :, :3] = R0 @ -geo.skew(Rp)
        JX[:, :, 3:6] = R0
        JR[:, :, :3] = -geo.skew(np.einsum("nij,j->ni", R0, x))
        JR[:, :, 3:] = np.eye(3)
        Jp = R0 @ R
    else:
        R0T = np.swapaxes(R0, 1, 2)
        JX[:, :, :3] = R0T @ -geo.skew(Rp)
        JX[:, :, 3:6] = R0T
        JR[:, :, :3] = R0T @ geo.skew(x - t0)
        JR[:, :, 3:] = -R0T
        Jp = R0T @ R
    return JX, JR, Jp


def point_error_budget(problem: Problem, ref: RefineResult, noise: NoiseAssumptions, shots_averaged: int = 1) -> dict:
    """RMS 3-D error (mm, k = 1) of a point measured at a new pose, per part, and the
    k = 2 total; ``shots_averaged`` > 1 gives the error of a quantity averaged over that
    many shots of one station (a sphere centre fitted from a sweep): the per-shot pose
    noise and the point noise average out, the station's offset does not."""
    pts = np.vstack(problem.profiles)
    # without profiles (centre observations only): where the sphere centres were seen,
    # brought into the laser plane
    p = np.array([0.0, *(pts.mean(axis=0) if len(pts) else ref.predicted[:, 1:].mean(axis=0))])
    JX, JR, Jp = _jacobians(problem, ref.R, ref.t, p)
    kt = ref.kinematic_terms
    S_shot = _pose_cov(noise) * ref.pose_noise_scale / shots_averaged
    S_point = np.diag([0.0, 1.0, 1.0]) * noise.point_noise_mm**2 / shots_averaged

    def rms(J, S):
        return float(np.sqrt(max(np.mean(np.einsum("nij,jk,nik->n", J, S, J)), 0.0)))  # rounding: never below 0

    if kt is not None and "identified_design" in kt:
        # through the identified model: transform, sphere and identified parameters jointly
        keep = list(range(9)) + list(range(kt["n_geo"], kt["covariance"].shape[0]))
        JX = np.concatenate([JX, JR @ kt["identified_design"]], axis=2)
        cov_X = kt["covariance"][np.ix_(keep, keep)]
        robot = 0.0
    elif kt is not None:
        cov_X = ref.covariance_without_robot_error[:9, :9]  # the noise's share; the robot's is below
        B = JR @ kt["design"] - JX @ kt["influence"][:9]
        # this arm's error as the fit sees it (posterior mean), and what it does not know of it
        mean = np.einsum("nij,j->ni", B, kt["posterior_mean"])
        robot = float(np.sqrt(np.mean(np.sum(mean**2, axis=1) + np.einsum("nij,jk,nik->n", B, kt["posterior_cov"], B))))
    else:
        # the transform's and the stations' shares at the same (estimated) station scales
        cov_X = next(c for c in (ref.covariance_robot_frame_at_scales, ref.covariance_robot_frame, ref.covariance)
                     if c is not None)[:9, :9]
        s_rot, s_trans = ref.station_effect_scales
        robot = rms(JR, np.diag([s_rot**2] * 3 + [s_trans**2] * 3))
    parts = {
        "transform_and_sphere_mm": rms(JX, cov_X),
        "robot_station_to_station_mm": robot,
        "robot_pose_noise_mm": rms(JR, S_shot),
        "sensor_point_noise_mm": 0.0 if shots_averaged > 1 else rms(Jp, S_point),
    }
    total = float(np.sqrt(sum(v**2 for v in parts.values())))
    return {"k2_mm": 2.0 * total, "rms_mm": total, "parts_rms_mm": parts,
            "sensor_point_mm": p.tolist(), "shots_averaged": shots_averaged}


def nominal_arm_point_error_k2_mm(problem: Problem, ref: RefineResult, budget: dict) -> float | None:
    """A kinematic calibration's transform used on the controller's nominal arm model (the
    arm's identified geometric error not applied): the expected error (k = 2, 3-D, mm) of a
    point measured at a new pose like the calibration's. None unless the arm's geometry was
    identified.

    At each calibration pose the nominal model puts the flange where the identified model
    does not; the point ``budget`` was evaluated at (``sensor_point_mm``) moves with it, to
    first order by ``JR D delta`` (``D`` the identified parameters' flange error design,
    ``delta`` their estimates). The part of that shift common to every pose moves the
    whole scene alike, as the robot's accuracy does in :func:`point_error_budget`, and is
    left out; the RMS of the rest joins ``budget``'s own RMS (the noise and the
    calibration's uncertainty) in quadrature."""
    kt = ref.kinematic_terms
    ke = ref.diagnostics.get("kinematic_effects")
    if kt is None or "identified_design" not in kt or not ke or ref.kinematic_errors is None:
        return None
    delta = np.asarray(ref.kinematic_errors, dtype=float)[np.flatnonzero(ke["identified"])]
    _, JR, _ = _jacobians(problem, ref.R, ref.t, np.asarray(budget["sensor_point_mm"], dtype=float))
    shift = np.einsum("nij,njk,k->ni", JR, kt["identified_design"], delta)
    spread = shift - shift.mean(axis=0)
    arm_rms = float(np.sqrt(np.mean(np.sum(spread**2, axis=1))))
    return 2.0 * float(np.hypot(budget["rms_mm"], arm_rms))


def station_prediction_summary(problem: Problem, ref: RefineResult) -> StationPrediction | None:
    """The leave-one-station-out figures of a kinematic calibration
    (:func:`.refine.crossval.station_cross_validation`) as the result keeps them, or None."""
    sp = ref.station_prediction
    if sp is None:
        return None
    dist = np.linalg.norm(sp["offset_mm"], axis=1)
    expected = np.trace(sp["expected_cov_mm2"], axis1=1, axis2=2)
    ok = np.isfinite(dist) & np.isfinite(expected)
    labels = list(problem.station_labels)
    per = {label: float(d) for label, d, good in zip(labels, dist, ok) if good}
    lost = [label for label, good in zip(labels, ok) if not good]
    return StationPrediction(
        rms_mm=float(np.sqrt(np.mean(dist[ok] ** 2))) if ok.any() else 0.0,
        expected_rms_mm=float(np.sqrt(np.mean(expected[ok]))) if ok.any() else 0.0,
        per_station_mm=per,
        worst_station=lost[0] if lost else max(per, key=per.get),
        unpredictable_stations=lost,
        in_sample_rms_mm=float(np.sqrt(np.mean(np.sum(sp["in_sample_mm"] ** 2, axis=1)))),
    )
