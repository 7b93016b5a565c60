"""Physical constants of vibro, defined once (import them; never write the number again)."""

from __future__ import annotations

import math

#: Gravitational acceleration (m/s^2), the value every vibro model, fit and synthetic rig uses.
G_MPS2: float = 9.81


def axial_gravity_mps2(axis_tilt_deg: float = 0.0) -> float:
    """Gravity along the rig's motion axis (m/s^2, pulling towards the lower plate) when the axis is tilted
    ``axis_tilt_deg`` from vertical as mounted (rig.yaml ``setup.axis_tilt_deg``): g cos(theta) with g =
    :data:`G_MPS2`; 0 (exactly) for a horizontal axis. What a free flight falls at along the axis; the ball's
    weight, which the physical floors are fractions of, stays m g."""
    theta = float(axis_tilt_deg)
    if theta == 90.0:
        return 0.0   # cos(pi/2) is 6e-17 in floating point: a horizontal axis has no gravity along it
    return G_MPS2 * math.cos(math.radians(theta))
