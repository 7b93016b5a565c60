"""Start-up cost: what a node or ``vibro --help`` imports before it does any work.

Every graph run starts eight node processes and every test calls the CLI in a fresh process, so the
start-up imports are paid many times over (scipy.stats ~1.5 s of CPU, scipy.signal ~1.7 s with
scipy.stats inside, matplotlib ~1 s on this machine; dask and distributed, which only campaigns and
chunked DIC use, ~1 s). These modules are loaded where they are used.
The property checked is which modules are loaded, not a time (no timing asserts: machines are noisy).
What replaced scipy.stats (chi-square and F tail probabilities, the normal Q-Q of the COR statistics,
Spearman's rho of the spin analysis) is checked against scipy.stats itself.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

HEAVY = ("scipy.stats", "scipy.signal", "matplotlib", "scipy.ndimage", "dask", "distributed")
NODES = ("vibro_dic.frame_source_node", "vibro_dic.dic_tracker_node", "vibro_fit.accel_source_node",
         "vibro_fit.impact_detector_node", "vibro_fit.trajectory_fitter_node", "vibro_sim.simulator_node",
         "vibro_discrepancy.discrepancy_node", "vibro_ros.recorder_node")


def _loaded_after(code: str) -> list[str]:
    probe = f"import sys\n{code}\nimport json\nprint(json.dumps(sorted(m for m in {HEAVY!r} if m in sys.modules)))"
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_no_node_loads_scipy_stats_signal_or_matplotlib_at_start_up() -> None:
    code = "\n".join(f"import {m}" for m in NODES)
    assert _loaded_after(code) == []


def test_the_cli_parser_loads_no_subcommand_work() -> None:
    code = "import vibro_app.cli as c\nc.build_parser()"
    assert _loaded_after(code) == []
    probe = ("import sys\nimport vibro_app.cli as c\nc.build_parser()\n"
             "print('scipy.optimize' in sys.modules, 'vibro_sim.synth.write' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert out.stdout.split() == ["False", "False"], out.stderr


@pytest.mark.parametrize("dof", [1, 2, 3.5, 10, 57])
def test_tail_probabilities_equal_scipy_stats(dof: float) -> None:
    from scipy import stats

    from vibro_model.tail_probability import chi2_sf, f_sf

    for x in (-2.0, 0.0, 1e-3, 0.7, 3.0, 12.0, 80.0, math.inf):
        assert chi2_sf(x, dof) == pytest.approx(float(stats.chi2.sf(x, dof)), rel=1e-12, abs=1e-300)
        for den in (2, 17.5, 300):
            assert f_sf(x, dof, den) == pytest.approx(float(stats.f.sf(x, dof, den)), rel=1e-12, abs=1e-300)
    assert math.isnan(chi2_sf(math.nan, dof)) and math.isnan(f_sf(math.nan, dof, 4))


def test_normal_check_equals_scipy_probplot() -> None:
    from scipy import stats

    from vibro_fit.statistics import normal_check

    rng = np.random.default_rng(4)
    for n in (3, 4, 9, 60, 401):
        for values in (rng.normal(0.7, 0.015, n), rng.exponential(1.0, n), np.round(rng.normal(0, 1, n), 1)):
            c = normal_check(values)
            (osm, osr), (slope, intercept, r) = stats.probplot(values, dist="norm")
            assert np.allclose(c.theoretical_quantiles, osm, rtol=0, atol=1e-12)
            assert np.array_equal(c.ordered_values, osr)
            assert (c.slope, c.intercept, c.r) == pytest.approx((slope, intercept, r), rel=1e-9, abs=1e-12)
    assert math.isnan(normal_check([0.5, 0.5, 0.5]).r)  # r undefined for a constant sample (scipy: nan)


def test_spin_correlation_equals_scipy_spearman() -> None:
    from scipy import stats

    from vibro_fit.spin import _spearman

    rng = np.random.default_rng(5)
    for n in (3, 5, 12, 80):
        for trial in range(12):
            x = rng.normal(size=n)
            y = (0.4 if trial % 2 else -0.9) * x + rng.normal(size=n)
            if trial % 3 == 0:
                x = np.round(x)  # ties
            if trial % 4 == 0:
                y = x * 2.0  # perfect rank correlation
            rho, p = _spearman(x, y)
            ref = stats.spearmanr(x, y)
            assert (rho, p) == pytest.approx((float(ref.statistic), float(ref.pvalue)), rel=1e-9, abs=1e-12)
