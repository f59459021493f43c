"""Each station predicted by the fit of the others: the error of a point at a new pose,
measured, for a kinematic calibration.

With the arm's geometry identified, the transform alone is not what a user relies on: a
point measured at a new pose is mapped through the calibrated arm *and* the transform,
and the two trade against each other along directions the data see only weakly (in
eye-to-hand, joint 2's origin against the transform's translation while joint 1 turns
little: a 1-sigma of the transform of tenths of a millimetre, a point's error of
hundredths). What the calibration promises is the prediction through both. This module
measures it by leaving each station out in turn, on the linearised model at the
solution: the fit of the other stations (transform, sphere, identified parameters and
the others' random effects, with their prior) places the sphere as the left-out
station's pose and its joints say; the station's own profiles place it where they see
it. The distance between the two is the error of a point at a pose the fit did not see,
the noise of the station's own sweep included; its expected covariance is that noise
plus the prediction's (the other stations' information, without this one).

It needs no refit: with ``N`` the normal matrix of the whole problem (random effects
whitened by their prior, ``+I``), ``N_k`` and ``b_k`` station k's share of it and of the
right-hand side, the fit without station k is ``u = (N - N_k)^-1 (b - b_k)``, exact for
the linearised model; the station's sphere offset is then a 3-parameter least-squares
fit to its own misfit. A station without which the others cannot determine the
parameters (a plan that does not identify the geometry) gets an infinite offset.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from spherecal.estimation.refine.linearisation import _Linearisation
    from spherecal.estimation.refine.state import RefineState

#: Fewest stations a left-out station is predicted from.
MIN_STATIONS = 3


def station_cross_validation(fit: RefineState, lin: _Linearisation) -> dict | None:
    """Leave-one-station-out prediction of the sphere at each station, for a kinematic
    calibration (identified parameters, no station effects, at least
    :data:`MIN_STATIONS` + 1 stations); None otherwise.

    Returns ``offset_mm`` (K, 3): where the station's profiles put the sphere centre less
    where the fit of the other stations puts it (sphere frame: base in eye-in-hand,
    flange in eye-to-hand), ``expected_cov_mm2`` (K, 3, 3): its covariance if the model
    holds (the station's own noise and the prediction's), and ``in_sample_mm`` (K, 3):
    the same offset against the fit of every station."""
    if fit.ke is None or not len(fit.id_cols) or fit.se is not None or fit.K < MIN_STATIONS + 1:
        return None
    At, _, Ak = fit.design(lin)
    red = lin.red
    n_fixed = At.shape[2]
    if Ak is not None:
        Lp = fit.sqrt_prior(fit.s_hat, fit.lam)
        D = np.concatenate([At, Ak @ Lp], axis=2)
        z = Ak @ fit.kappa[fit.rand_cols]  # the random effects as estimated, per shot
    else:
        D, z = At, np.zeros((fit.n_shots, 4))
    prior = np.zeros((D.shape[2], D.shape[2]))
    prior[n_fixed:, n_fixed:] = np.eye(D.shape[2] - n_fixed)
    N = red.gram(D, D) + prior
    b = red.rhs(D, z)
    u_all = np.linalg.lstsq(N, b, rcond=None)[0]
    Cc = lin.columns(lin.Jc[:, :, 6:9])  # a shift of the sphere centre, seen at each shot
    offsets, covs, inside = [], [], []
    for rows in fit.station_shots:
        G = red.gram(Cc[rows], Cc[rows], rows)
        H = np.linalg.solve(G, red.gram(Cc[rows], D[rows], rows))

        def offset(u):
            v = np.zeros((fit.n_shots, 4))
            v[rows] = z[rows] - D[rows] @ u  # the station's misfit left by u
            return np.linalg.solve(G, red.rhs(Cc[rows], v, rows))

        inside.append(offset(u_all))
        N_out = N - red.gram(D[rows], D[rows], rows)
        try:
            u = np.linalg.solve(N_out, b - red.rhs(D[rows], z, rows))
            cov = np.linalg.inv(G) + H @ np.linalg.solve(N_out, H.T)
            d = offset(u)
        except np.linalg.LinAlgError:
            d, cov = np.full(3, np.inf), np.full((3, 3), np.inf)
        if not (np.all(np.isfinite(d)) and np.all(np.isfinite(cov))):
            d, cov = np.full(3, np.inf), np.full((3, 3), np.inf)
        offsets.append(d)
        covs.append(cov)
    return {"offset_mm": np.array(offsets), "expected_cov_mm2": np.array(covs), "in_sample_mm": np.array(inside)}
