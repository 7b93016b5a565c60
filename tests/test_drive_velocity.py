"""The structure's velocity at each impact where the drive changed during the take (vibro_fit.drive_velocity).

Ground truth: an analytic structure whose amplitude ramps linearly (its velocity known exactly), and the
synthetic rig's ``drive_change`` (amplitude +10 % over 0.1 s at 0.75 s) with its true impacts. Tolerances: 4 of
the stated sigma for single values, and for the Monte Carlo of the sigma itself 4 of the sampling error of a
standard deviation over N draws (1 / sqrt(2 (N - 1)) relative).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from discrepancy_cases import make_case

import vibro_fit.drive_velocity as dv
from vibro_fit.identify import identify
from vibro_fit.structure_fit import fit_structure

F_HZ, FPS = 22.0, 1000.0
W = 2 * math.pi * F_HZ
NOISE_MM = 2e-4          # DIC structure noise on the rendered recordings, ~0.2 um


def _ramp(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(position mm, velocity mm/s) of a 1.4 mm sine whose amplitude rises 10 % linearly over 0.75-0.85 s."""
    a = 1.4 * (1 + 0.1 * np.clip((t - 0.75) / 0.1, 0.0, 1.0))
    da = np.where((t > 0.75) & (t < 0.85), 1.4, 0.0)        # mm/s during the ramp
    return a * np.sin(W * t + 0.3), da * np.sin(W * t + 0.3) + a * W * np.cos(W * t + 0.3)


def test_the_local_fit_follows_a_ramp_the_window_sine_misses() -> None:
    t = np.arange(0, 1.5, 1 / FPS)
    y, _ = _ramp(t)
    y = y + np.random.default_rng(0).normal(0, NOISE_MM, t.size)
    worst_window = 0.0
    for t_i in np.arange(0.77, 0.84, 0.0113):     # impacts inside the ramp
        _, v_true = _ramp(np.array([t_i]))
        local = dv.local_velocity(t, y, float(t_i), F_HZ)
        assert local is not None and local.n_points >= dv.MIN_POINTS
        assert abs(local.v_mps - 1e-3 * v_true[0]) < 4 * local.sd_mps + 1e-6, (t_i, local, v_true)
        # the streaming fitter's window: a period before the flight before, to the end of the flight after
        win = (t >= t_i - 1 / F_HZ - 0.022) & (t <= t_i + 0.022)
        s = fit_structure(t[win], y[win], f0_hz=F_HZ)
        worst_window = max(worst_window, abs(float(s.velocity_mps(t_i)) - 1e-3 * v_true[0]))
    assert worst_window > 1e-3, worst_window      # the premise: the window's one sine misses by mm/s


def test_the_local_sigma_holds_on_a_steady_drive() -> None:
    t = np.arange(0, 0.3, 1 / FPS)
    t_i = 0.1503
    v_true = 1e-3 * 1.4 * W * math.cos(W * t_i + 0.3)
    rng = np.random.default_rng(5)
    n = 300
    fits = [dv.local_velocity(t, 1.4 * np.sin(W * t + 0.3) + rng.normal(0, NOISE_MM, t.size), t_i, F_HZ)
            for _ in range(n)]
    err = np.array([f.v_mps - v_true for f in fits])
    sd = float(np.mean([f.sd_mps for f in fits]))
    assert abs(err.mean()) < 4 * sd / math.sqrt(n)                          # unbiased
    assert abs(err.std(ddof=1) / sd - 1) < 4 / math.sqrt(2 * (n - 1))      # the stated sigma is the scatter


def test_too_few_frames_or_one_side_only_gives_no_velocity() -> None:
    t = np.arange(0, 0.2, 1 / FPS)
    y = np.sin(W * t)
    assert dv.local_velocity(t, y, 0.0, F_HZ) is None                       # nothing before the impact
    assert dv.local_velocity(t[::4], y[::4], 0.1, F_HZ) is None             # 12 frames in the window
    assert dv.local_velocity(t, y, 0.1, 0.0) is None


@pytest.fixture(scope="module")
def changing_drive():
    _, track, rig, truth = make_case({"drive_change": {}}, seed=2, frames=1500, cor_scatter=0.015)
    return track, rig, truth


def _errors(ident, truth) -> np.ndarray:
    """(|COR error|, its sigma) of every impact with a COR against the true impact nearest in time."""
    tt = np.array([i["t"] for i in truth["impacts"]])
    te = np.array([i["cor"] for i in truth["impacts"]])
    rows = [(abs(i.cor - te[int(np.argmin(np.abs(tt - i.t_s)))]), i.cor_std) for i in ident.impacts
            if i.cor is not None and math.isfinite(i.cor)]
    return np.array(rows)


def test_a_changing_drive_leaves_no_cor_wrong_beyond_its_sigma(changing_drive, monkeypatch) -> None:
    track, rig, truth = changing_drive
    ident = identify(track, rig)
    assert ident.drive is not None and ident.drive.stationary is False
    notes = [w for w in ident.warnings if "velocity at" in w]
    assert len(notes) == 1 and "impacts taken from a fit of half a period" in notes[0]
    e = _errors(ident, truth)
    assert e[:, 0].max() < 0.002 and np.all(e[:, 0] < 4 * e[:, 1]), e[np.argmax(e[:, 0])]
    monkeypatch.setattr(dv, "SHIFT_SIGMAS", math.inf)      # the premise: without the pass, the ramp's impacts miss
    before = _errors(identify(track, rig), truth)
    assert before[:, 0].max() > 0.004


def test_a_steady_drive_is_left_to_eq_16() -> None:
    _, track, rig, _ = make_case({}, seed=2, frames=1500)      # 8 windows: the drive is tested
    ident = identify(track, rig)
    assert ident.drive is not None and ident.drive.stationary is True
    assert not [w for w in ident.warnings if "velocity at" in w]
    impacts = list(ident.impacts)
    assert dv.drive_velocity_pass(impacts, track.t_s, track.structure_mm, F_HZ, True) == (impacts, [])
    assert dv.drive_velocity_pass(impacts, track.t_s, track.structure_mm, F_HZ, None) == (impacts, [])
