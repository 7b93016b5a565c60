"""Impact time (Eq. 15), COR (Eq. 16) and its propagated uncertainty; finite-difference baseline."""

from __future__ import annotations

import numpy as np
import pytest

from vibro_fit.flight_fit import fit_flight
from vibro_fit.impacts import finite_difference_cor, gap_root, paper_impact
from vibro_fit.structure_fit import fit_structure
from vibro_fit.synthetic import simulate

FPS = 1000.0


def test_gap_root_picks_the_root_inside_the_gap_never_outside():
    # p(t) = 0, q(t) = 50 (t - 0.0105)(t - 0.0300): roots at 10.5 ms (inside the gap 10..12 ms) and
    # 30 ms (outside). The inside one must be returned.
    p = np.array([0.0, 0.0, 0.0])
    q = np.array([50.0, -50.0 * (0.0105 + 0.03), 50.0 * 0.0105 * 0.03])
    t = gap_root(p, 0.0, q, 0.0, 0.010, 0.012)
    assert t == pytest.approx(0.0105, abs=1e-12)
    # gap that holds neither root: no impact rather than a spurious one
    assert gap_root(p, 0.0, q, 0.0, 0.012, 0.014) is None


def test_gap_root_linear_case():
    # equal curvature: Eq. 15 degenerates to a line; root at 5.3 ms
    p = np.array([-4900.0, 100.0, 0.0])
    q = np.array([-4900.0, -300.0, 400.0 * 0.0053])
    assert gap_root(p, 0.0, q, 0.0, 0.004, 0.007) == pytest.approx(0.0053, abs=1e-12)


def _frames_around(truth, k_imp, fps=FPS):
    """Frame indices of the flight before and after impact k_imp (frames next to impacts excluded)."""
    ti = [i.t_s for i in truth.impacts]
    prev_t, t_i, next_t = ti[k_imp - 1], ti[k_imp], ti[k_imp + 1]
    # frames strictly inside each flight, minus the frame next to each impact
    fb = np.arange(int(np.floor(prev_t * fps)) + 2, int(np.floor(t_i * fps)))
    fa = np.arange(int(np.floor(t_i * fps)) + 2, int(np.floor(next_t * fps)))
    return fb, fa


def _one_impact(truth, k_imp, noise_mm, rng, n_frames=600):
    t = np.arange(n_frames) / FPS
    ball = 1e3 * truth.ball_m(t) + noise_mm * rng.standard_normal(n_frames)
    st = 1e3 * truth.structure_m(t) + noise_mm * rng.standard_normal(n_frames)
    fb, fa = _frames_around(truth, k_imp)
    p = fit_flight(0, fb, t, ball)
    q = fit_flight(1, fa, t, ball)
    sel = (t >= t[fb[0]] - 1 / 22.0) & (t <= t[fa[-1]])
    s_fit = fit_structure(t[sel], st[sel], f0_hz=22.0)
    return paper_impact(0, p, q, s_fit), t, ball, st


def test_noise_free_recovers_exact_impact():
    truth = simulate(amplitude_m=3e-3, duration_s=0.6, cor_jitter=0.05, seed=3)
    for k in (5, 6, 7, 8):
        est, *_ = _one_impact(truth, k, 0.0, np.random.default_rng(0))
        ti = truth.impacts[k]
        # exact parabolas and sine: only round-off and the solver tolerance (1e-12) remain
        assert est.t_s == pytest.approx(ti.t_s, abs=1e-9)
        assert est.cor == pytest.approx(ti.cor, abs=1e-7)
        assert est.plate == ti.plate
        assert est.v_ball_before_mps == pytest.approx(ti.v_ball_before_mps, abs=1e-6)
        assert est.v_ball_after_mps == pytest.approx(ti.v_ball_after_mps, abs=1e-6)
        assert est.v_structure_mps == pytest.approx(ti.v_structure_mps, abs=1e-6)


def test_cor_std_matches_monte_carlo():
    # First-order propagation vs Monte-Carlo over 300 noise draws (sigma = 0.005 mm, 10x the DIC noise):
    # the sample std of 300 draws has a relative scatter 1/sqrt(600) = 4 %; the mean predicted std is
    # averaged over the same draws. 20 % tolerance = 5 x that scatter; the mean error must stay
    # within 5 standard errors (unbiased estimator to first order).
    truth = simulate(amplitude_m=3e-3, duration_s=0.6, seed=4)
    k = 6
    rng = np.random.default_rng(11)
    cors, stds, ts, tstds = [], [], [], []
    for _ in range(300):
        est, *_ = _one_impact(truth, k, 0.005, rng)
        cors.append(est.cor)
        stds.append(est.cor_std)
        ts.append(est.t_s)
        tstds.append(est.t_std_s)
    cors = np.array(cors)
    emp = cors.std(ddof=1)
    pred = np.sqrt(np.mean(np.square(stds)))
    assert pred == pytest.approx(emp, rel=0.2)
    assert abs(cors.mean() - truth.impacts[k].cor) < 5 * emp / np.sqrt(300)
    emp_t = np.std(ts, ddof=1)
    assert np.sqrt(np.mean(np.square(tstds))) == pytest.approx(emp_t, rel=0.2)


def test_finite_difference_baseline_is_biased_fit_is_not():
    # The central-difference velocities are taken 1.5 frames from the impact, where the relative
    # velocity differs from its value at impact by (g + Ys'') x 1.5 ms ~ 0.1 m/s out of ~1 m/s:
    # a COR error of several percent even without noise; the fitted COR is exact (1e-7).
    truth = simulate(amplitude_m=3e-3, duration_s=0.6, seed=5)
    errs_fd, errs_fit = [], []
    for k in (5, 6, 7, 8):
        est, t, ball, st = _one_impact(truth, k, 0.0, np.random.default_rng(0))
        e_fd = finite_difference_cor(t, ball, st, est.t_s)
        errs_fd.append(abs(e_fd - truth.impacts[k].cor))
        errs_fit.append(abs(est.cor - truth.impacts[k].cor))
    assert np.mean(errs_fd) > 0.005
    assert np.mean(errs_fit) < 1e-6
