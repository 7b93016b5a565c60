"""Physical constants of vibro, defined once (import them; never write the number again)."""

from __future__ import annotations

#: Gravitational acceleration (m/s^2), the value every vibro model, fit and synthetic rig uses.
G_MPS2: float = 9.81
