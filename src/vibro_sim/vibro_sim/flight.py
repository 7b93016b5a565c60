"""Exact free-flight solutions of m y'' = -m g_eff + F(v) on one segment (SI, lab frame).

A segment starts at (t0, y0, v0) and holds while the force law keeps one analytic form:
a constant acceleration (no force, per-flight force, Coulomb between sign changes),
viscous drag (exponential), quadratic drag (tan / tanh / coth forms, split at the
apex), or a numerical dense solution for any other law. ``t_natural_end`` is where the
form changes (the apex for Coulomb/quadratic) or +inf. Each segment also gives bounds
on |y''|, |y'''| and |y''''| over the segment, used by the event scanner.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

INF = math.inf


class Segment:
    """One analytic piece of the ball's trajectory starting at t0."""

    t0: float
    t_natural_end: float = INF
    label: str = "flight"

    def pos(self, t):
        raise NotImplementedError

    def vel(self, t):
        raise NotImplementedError

    def acc(self, t):
        raise NotImplementedError

    def jerk(self, t):
        raise NotImplementedError

    def bounds(self) -> tuple[float, float, float]:
        """Upper bounds of (|y''|, |y'''|, |y''''|) over the segment."""
        raise NotImplementedError


class ConstAccel(Segment):
    """y = y0 + v0 tau + a tau^2 / 2 (a parabola), tau = t - t0."""

    def __init__(self, t0: float, y0: float, v0: float, a: float, t_natural_end: float = INF):
        self.t0, self.y0, self.v0, self.a = t0, y0, v0, a
        self.t_natural_end = t_natural_end

    def pos(self, t):
        tau = np.asarray(t, dtype=float) - self.t0
        return self.y0 + tau * (self.v0 + 0.5 * self.a * tau)

    def vel(self, t):
        return self.v0 + self.a * (np.asarray(t, dtype=float) - self.t0)

    def acc(self, t):
        return np.full_like(np.asarray(t, dtype=float), self.a)

    def jerk(self, t):
        return np.zeros_like(np.asarray(t, dtype=float))

    def bounds(self):
        return abs(self.a), 0.0, 0.0


class ViscousFlight(Segment):
    """y'' = a_g - k y' (k = c/m): v = v_inf + (v0 - v_inf) exp(-k tau), v_inf = a_g / k."""

    def __init__(self, t0: float, y0: float, v0: float, a_g: float, k: float):
        self.t0, self.y0, self.v0, self.k = t0, y0, v0, k
        self.v_inf = a_g / k
        self.dv = v0 - self.v_inf

    def pos(self, t):
        tau = np.asarray(t, dtype=float) - self.t0
        return self.y0 + self.v_inf * tau - self.dv * np.expm1(-self.k * tau) / self.k

    def vel(self, t):
        tau = np.asarray(t, dtype=float) - self.t0
        return self.v_inf + self.dv * np.exp(-self.k * tau)

    def acc(self, t):
        tau = np.asarray(t, dtype=float) - self.t0
        return -self.k * self.dv * np.exp(-self.k * tau)

    def jerk(self, t):
        tau = np.asarray(t, dtype=float) - self.t0
        return self.k ** 2 * self.dv * np.exp(-self.k * tau)

    def bounds(self):
        a = abs(self.k * self.dv)
        return a, a * self.k, a * self.k ** 2


def _log_cosh(x):
    x = np.abs(x)
    return x + np.log1p(np.exp(-2.0 * x)) - math.log(2.0)


def _log_sinh(x):  # x > 0
    return x + np.log1p(-np.exp(-2.0 * x)) - math.log(2.0)


class QuadraticUp(Segment):
    """Rising (v0 > 0) under y'' = -g - kappa v^2: v = vt tan(th0 - s tau); ends at the apex."""

    def __init__(self, t0: float, y0: float, v0: float, g: float, kappa: float):
        self.t0, self.y0, self.v0, self.g, self.kappa = t0, y0, v0, g, kappa
        self.vt = math.sqrt(g / kappa)
        self.s = math.sqrt(g * kappa)
        self.th0 = math.atan(v0 / self.vt)
        self.t_natural_end = t0 + self.th0 / self.s

    def _th(self, t):
        return self.th0 - self.s * (np.asarray(t, dtype=float) - self.t0)

    def pos(self, t):
        return self.y0 + (np.log(np.cos(self._th(t))) - math.log(math.cos(self.th0))) / self.kappa

    def vel(self, t):
        return self.vt * np.tan(self._th(t))

    def acc(self, t):
        v = self.vel(t)
        return -self.g - self.kappa * v * v

    def jerk(self, t):
        v = self.vel(t)
        return -2.0 * self.kappa * v * self.acc(t)

    def bounds(self):
        a = self.g + self.kappa * self.v0 ** 2
        j = 2 * self.kappa * self.v0 * a
        return a, j, 2 * self.kappa * (a * a + self.v0 * j)


class QuadraticDown(Segment):
    """Falling (v0 <= 0) under y'' = -g + kappa v^2, speed u = -v -> vt (tanh or coth form)."""

    def __init__(self, t0: float, y0: float, v0: float, g: float, kappa: float):
        self.t0, self.y0, self.g, self.kappa = t0, y0, g, kappa
        self.vt = math.sqrt(g / kappa)
        self.s = math.sqrt(g * kappa)
        u0 = -v0
        self.v0 = v0
        if abs(u0 - self.vt) <= 1e-15 * self.vt:
            self.mode = "terminal"
            self.phi0 = 0.0
        elif u0 < self.vt:
            self.mode = "tanh"
            self.phi0 = math.atanh(u0 / self.vt)
        else:
            self.mode = "coth"
            self.phi0 = math.atanh(self.vt / u0)

    def _phi(self, t):
        return self.phi0 + self.s * (np.asarray(t, dtype=float) - self.t0)

    def pos(self, t):
        if self.mode == "terminal":
            return self.y0 - self.vt * (np.asarray(t, dtype=float) - self.t0)
        if self.mode == "tanh":
            return self.y0 - (_log_cosh(self._phi(t)) - _log_cosh(self.phi0)) / self.kappa
        return self.y0 - (_log_sinh(self._phi(t)) - _log_sinh(self.phi0)) / self.kappa

    def vel(self, t):
        if self.mode == "terminal":
            return np.full_like(np.asarray(t, dtype=float), -self.vt)
        if self.mode == "tanh":
            return -self.vt * np.tanh(self._phi(t))
        return -self.vt / np.tanh(self._phi(t))

    def acc(self, t):
        v = self.vel(t)
        return -self.g + self.kappa * v * v

    def jerk(self, t):
        v = self.vel(t)
        return 2.0 * self.kappa * v * self.acc(t)

    def bounds(self):
        vmax = max(abs(self.v0), self.vt)
        a = max(self.g, abs(self.kappa * self.v0 ** 2 - self.g))
        j = 2 * self.kappa * vmax * a
        return a, j, 2 * self.kappa * (a * a + vmax * j)


class NumericFlight(Segment):
    """Any force law: DOP853 dense solution of y'' = -g_eff + F(v)/m over [t0, t_stop]."""

    def __init__(self, t0: float, y0: float, v0: float, accel_fn, t_stop: float):
        self.accel_fn = accel_fn
        self._integrate(t0, y0, v0, t_stop, lambda t, y, v: accel_fn(v))

    def _integrate(self, t0: float, y0: float, v0: float, t_stop: float, accel_tyv) -> None:
        """DOP853 dense solution of y'' = accel_tyv(t, y, v) over [t0, t_stop] (SI), and bounds on |a| and |a'|
        from 200 samples of it (doubled and quadrupled: the event search's margins)."""
        self.t0 = t0
        self.t_natural_end = t_stop
        sol = solve_ivp(lambda t, s: (s[1], accel_tyv(t, s[0], s[1])), (t0, t_stop), (y0, v0),
                        method="DOP853", rtol=1e-12, atol=1e-15, dense_output=True)
        if not sol.success:  # pragma: no cover - solver failure
            raise RuntimeError(f"free-flight integration failed: {sol.message}")
        self.sol = sol.sol
        grid = np.linspace(t0, t_stop, 200)
        y, v = self.sol(grid)
        a = np.array([accel_tyv(t, yy, vv) for t, yy, vv in zip(grid, y, v)])
        self._amax = 2.0 * float(np.max(np.abs(a))) + 1e-9
        da = np.abs(np.diff(a)) / max(grid[1] - grid[0], 1e-300)
        self._jmax = 4.0 * float(np.max(da, initial=0.0)) + 1e-6

    def pos(self, t):
        out = self.sol(np.asarray(t, dtype=float))[0]
        return out if np.ndim(t) else float(out)

    def vel(self, t):
        out = self.sol(np.asarray(t, dtype=float))[1]
        return out if np.ndim(t) else float(out)

    def acc(self, t):
        v = np.atleast_1d(self.vel(t))
        out = np.array([self.accel_fn(x) for x in v])
        return out if np.ndim(t) else float(out[0])

    def jerk(self, t):
        h = 1e-7
        return (np.asarray(self.acc(np.asarray(t) + h)) - np.asarray(self.acc(np.asarray(t) - h))) / (2 * h)

    def bounds(self):
        return self._amax, self._jmax, self._jmax * 1e4


class StateFlight(NumericFlight):
    """A force that depends on time and position too (kind ``"state"``: ``force.force_state_n(t, y, v)``):
    DOP853 dense solution of y'' = accel_fn(t, y, v) over [t0, t_stop]."""

    def __init__(self, t0: float, y0: float, v0: float, accel_fn, t_stop: float):
        self.state_fn = accel_fn
        self._integrate(t0, y0, v0, t_stop, accel_fn)

    def acc(self, t):
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        y, v = self.sol(tt)
        out = np.array([self.state_fn(a, b, c) for a, b, c in zip(tt, y, v)])
        return out if np.ndim(t) else float(out[0])


class Stuck(Segment):
    """The ball rides on a plate: y = Y_s(t) + side * b (side +1 top, -1 bottom)."""

    label = "stuck"

    def __init__(self, t0: float, structure, free_play_m: float, plate: str):
        self.t0 = t0
        self.structure = structure
        self.plate = plate
        self.offset = free_play_m if plate == "top" else -free_play_m

    def pos(self, t):
        return self.structure.position(t) + self.offset

    def vel(self, t):
        return self.structure.velocity(t)

    def acc(self, t):
        return self.structure.acceleration(t)

    def jerk(self, t):
        return self.structure.jerk(t)

    def bounds(self):
        s = self.structure
        return s.bound(2), s.bound(3), s.bound(4)


def make_flight_segment(t0: float, y0: float, v0: float, force, flight_index: int,
                        mass_kg: float, g_eff: float, t_limit: float) -> Segment:
    """The analytic segment starting at (t0, y0, v0) for ``force`` during flight ``flight_index``."""
    kind = getattr(force, "kind", "ode")
    if kind == "constant":
        return ConstAccel(t0, y0, v0, -g_eff + force.constant_n(flight_index) / mass_kg)
    if kind == "coulomb":
        f_over_m = force.magnitude_n / mass_kg
        if v0 > 0:
            a = -g_eff - f_over_m
            return ConstAccel(t0, y0, v0, a, t0 + v0 / -a if a < 0 else INF)
        if v0 < 0:
            a = -g_eff + f_over_m
            return ConstAccel(t0, y0, v0, a, t0 + v0 / -a if a > 0 else INF)
        # At rest: static friction holds the ball if it can (|g_eff| <= F/m).
        if abs(g_eff) <= f_over_m:
            return ConstAccel(t0, y0, 0.0, 0.0)
        return ConstAccel(t0, y0, 0.0, -g_eff + math.copysign(f_over_m, g_eff))
    if kind == "viscous":
        k = force.coefficient_ns_per_m / mass_kg
        if k == 0.0:
            return ConstAccel(t0, y0, v0, -g_eff)
        return ViscousFlight(t0, y0, v0, -g_eff, k)
    if kind == "quadratic" and g_eff > 0:
        kappa = force.coefficient_ns2_per_m2 / mass_kg
        if kappa == 0.0:
            return ConstAccel(t0, y0, v0, -g_eff)
        if v0 > 0:
            return QuadraticUp(t0, y0, v0, g_eff, kappa)
        return QuadraticDown(t0, y0, v0, g_eff, kappa)
    # General law: integrate numerically over a bounded window, then continue.
    t_stop = min(t_limit, t0 + 0.05)
    if t_stop <= t0:
        t_stop = t0 + 1e-6
    if kind == "state":
        return StateFlight(t0, y0, v0, lambda t, y, v: -g_eff + force.force_state_n(t, y, v) / mass_kg, t_stop)
    return NumericFlight(t0, y0, v0, lambda v: -g_eff + force.force_n(v, flight_index) / mass_kg, t_stop)
