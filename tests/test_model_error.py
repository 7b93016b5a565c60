"""Issue 39: an impact's COR sigma includes what the model leaves in its residuals (vibro_model.model_error).

Ground truth: the synthetic rig's physics with white DIC noise (tests/discrepancy_cases.py) and, for the unit
rules, samples drawn here. Properties: pure noise adds nothing (a model that fits keeps its sigma); a bias of
the slopes is found at its size; on a recording the paper's parabolas describe only approximately (a force that
depends on the ball's position: no catalogue term fits it, so the paper's values stay), 2-sigma coverage of the
true CORs goes from about half to the nominal share, with sigmas still of the size of the errors.
"""

from __future__ import annotations

import numpy as np
import pytest
from discrepancy_cases import make_case

from vibro_discrepancy.engine import run_discrepancy
from vibro_discrepancy.reidentify import reidentification
from vibro_model.assemble import apply_reidentification
from vibro_model.model_error import MIN_POOL, flight_residual_slope, pooled_bias_variance
from vibro_model.results import ResultsDocument


def test_pooled_noise_adds_nothing_and_a_bias_is_found_at_its_size():
    rng = np.random.default_rng(0)
    sd, n = 1e-4, 40
    false_alarms = sum(pooled_bias_variance(zip(rng.normal(0.0, sd, n), np.full(n, sd))) > 0 for _ in range(400))
    assert false_alarms <= 0.02 * 400            # two 3-sigma tests: ~0.3 % each
    for bias in (2 * sd, -3 * sd):               # a bias of one sign, twice and three times one slope's sigma
        est = [pooled_bias_variance(zip(rng.normal(bias, sd, n), np.full(n, sd))) for _ in range(50)]
        # the squared mean's sampling error: 2 |b| sd / sqrt(n) (plus sd^2 / n)
        tol = 3 * (2 * abs(bias) * sd / np.sqrt(n) + sd ** 2 / n)
        assert abs(np.median(est) - bias ** 2) < tol
    assert pooled_bias_variance([(1.0, 0.1)] * (MIN_POOL - 1)) == 0.0     # too few to tell


def test_a_flights_cubic_residual_gives_its_end_slope():
    tau = np.arange(40) / 1000.0
    x = (tau - tau.mean()) / (0.5 * np.ptp(tau))
    c3, noise = 2e-6, 1e-7
    r = c3 * 0.5 * (5 * x ** 3 - 3 * x) + np.random.default_rng(1).normal(0.0, noise, tau.size)
    d, sd = flight_residual_slope(tau, r, tau[-1] + 0.001)
    xa = (tau[-1] + 0.001 - tau.mean()) / (0.5 * np.ptp(tau))
    exact = c3 * 0.5 * (15 * xa ** 2 - 3) / (0.5 * np.ptp(tau))
    assert abs(d - exact) < 4 * sd and sd < 0.1 * abs(exact)
    d0, sd0 = flight_residual_slope(tau, np.random.default_rng(2).normal(0.0, noise, tau.size), tau[-1])
    assert abs(d0) < 4 * sd0


def _coverage(effects: dict) -> tuple[float, float, float, list[str]]:
    """(2-sigma coverage, median |error|, median sigma, cor methods) of the published CORs over two seeds."""
    errs, sds, methods = [], [], set()
    for seed in (1, 2):
        sections, track, rig, truth = make_case(effects, seed=seed, frames=1500)
        doc = ResultsDocument.from_dict(sections)
        run = run_discrepancy(doc, track, rig)
        final = apply_reidentification(doc, reidentification(run.result.findings, run))
        tt = np.array([i["t"] for i in truth["impacts"]])
        te = np.array([i["cor"] for i in truth["impacts"]])
        for imp in final.impacts:
            if imp.cor is None or imp.cor_std is None:
                continue
            k = int(np.argmin(np.abs(tt - imp.t_s)))
            errs.append(imp.cor - te[k])
            sds.append(imp.cor_std)
            methods.add(imp.cor_method)
    e, s = np.abs(np.array(errs)), np.array(sds)
    return float(np.mean(e < 2 * s)), float(np.median(e)), float(np.median(s)), sorted(methods)


def test_an_approximate_model_says_so_in_its_sigmas():
    cover, err, sd, methods = _coverage({"position_force": {"weight_fraction": 0.25, "decay_mm": 3.0}})
    assert methods == ["paper"]                   # the premise: no catalogue model measures these impacts
    assert err > 5e-4                             # ... and the paper's CORs are off by more than DIC noise
    assert cover >= 0.9                           # was 0.49 with the noise-only sigmas
    assert sd < 5 * err                           # honest, not useless


@pytest.mark.parametrize("effects", [{}, {"quadratic_drag": {"coefficient_ns2_per_m2": 5e-4}}])
def test_a_model_that_fits_keeps_its_sigmas(effects):
    cover, err, sd, _ = _coverage(effects)
    # noise-sized sigmas (DIC noise 0.25 um gives CORs ~1e-5 .. 1e-4), not widened by noise-sized residual shapes
    assert sd < 4 * err and sd < 2e-4
    # the goal on every recording; with the drag's shared coefficient in the sigma (it moves every COR
    # the same way: without it 0.85-0.88 here, 0.53-1.00 over eight seeds)
    assert cover >= 0.9
