"""Parameter sets shared by the tests (import from cases)."""

import math

#: Figure 1 of the polar-banana paper: v0 = 280 m/s, t = 10 s, sigma_a = 5/3 m/s^2,
#: sigma_omega = pi/54 rad/s.
FIG1 = dict(v0=280.0, t=10.0, sigma_a=5.0 / 3.0, sigma_omega=math.pi / 54.0)

#: A folding banana: sigma_omega t = 120 deg, so turns beyond 180 deg are common and the banana
#: overlaps itself (several roots per point).
FOLDING = dict(v0=280.0, t=10.0, sigma_a=5.0 / 3.0, sigma_omega=math.radians(12.0))

#: Figure 1 frame: x in [-3000, 3000] m, y in [-200, 3400] m.
FIG1_BOUNDS = dict(x=(-3000.0, 3000.0), y=(-200.0, 3400.0))


def small_scene(name: str, layers: str) -> str:
    """A small valid scene named ``name`` (200 m x 200 m at 10 m, a slow target) with the given
    ``[layers.*]`` tables appended."""
    return f"""\
[scene]
name = "{name}"

[grid]
x = [-100.0, 100.0]
y = [0.0, 200.0]
step = 10.0

[defaults]
v0 = 10.0
t = 5.0
sigma_a = 1.0
sigma_omega_deg = 10.0

{layers}"""
