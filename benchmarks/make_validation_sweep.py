"""Writes sweeps/cassie_validation.toml: the validation set of docs/cassie_protocol (pushes,
noise, speed x turn-rate circles) as one sweep of explicit scenarios, so that the whole set
runs in one compiled call.  The straight-line speeds and the in-place runs, which last 30-60 s,
are docs/experiments/cassie_speeds_val.toml.

    python benchmarks/make_validation_sweep.py
"""

from __future__ import annotations

import pathlib

OUT = pathlib.Path(__file__).resolve().parents[1] / "sweeps" / "cassie_validation.toml"

HEAD = '''# Validation set of the Cassie controller (docs/cassie_protocol; never tuned on), written by
# benchmarks/make_validation_sweep.py: 148 robots.
#  - pushes: line at 0.5 m/s, one 0.1 s pelvis push at t = 8.00 + 0.04 i s (i = 0..15), towards
#    +y and -y, of 100 N and 200 N (64 robots, 14 s);
#  - noise: noise_v 0.03 m/s, step_error 0.015 m on a line, a circle R = 1.5 m, a sinusoid
#    A = 0.5 m, wavelength 4 m, and a 2 m square, all at 0.5 m/s, seeds 100-115 (64 robots, 20 s);
#  - envelope: circles of radius 0.5, 1, 2, 4 m at peak speeds 0.25-1.25 m/s (20 robots, 20 s).
name = "cassie_validation"
description = "Validation: 64 pushes, 64 noisy runs, 20 circles of speed x turn rate"

[base]
plant = "cassie"
seed = 0
duration = 20.0

[base.cassie]
gait = "paper"

[base.mpc]
horizon = 6
w_pos = 1.0
w_vel = 1.0
alpha = 0.01

[base.path]
peak_speed = 0.5
accel = 0.25
profile = "trapezoid"
'''

NOISE_PATHS = (
    ("line", 'shape = "line"\nlength = 12.0'),
    ("circle-r1.5", 'shape = "circle"\nradius = 1.5'),
    ("sinusoid-a0.5", 'shape = "sinusoid"\namplitude = 0.5\nwavelength = 4.0\nperiods = 3.0'),
    ("square-2m", 'shape = "square"\nside = 2.0'),
)


def pushes():
    for force in (100.0, 200.0):
        for side, direction in (("left", 90.0), ("right", -90.0)):
            for i in range(16):
                t = round(8.0 + 0.04 * i, 2)
                yield (f'[[paths]]\nname = "push-{force:g}-{side}-{t:.2f}"\nshape = "line"\n'
                       f'length = 10.0\n[paths.overrides]\nduration = 14.0\n'
                       f'[[paths.overrides.disturbance.pushes]]\ntime = {t}\nduration = 0.1\n'
                       f'force = {force}\ndirection = {direction}\n')


def noise():
    for name, shape in NOISE_PATHS:
        for seed in range(100, 116):
            yield (f'[[paths]]\nname = "noise-{name}-seed{seed}"\n{shape}\n[paths.overrides]\n'
                   f'seed = {seed}\n[paths.overrides.disturbance]\nnoise_v = 0.03\n'
                   f'step_error = 0.015\n')


def envelope():
    for radius, laps in ((0.5, 10), (1.0, 6), (2.0, 3), (4.0, 2)):
        for v in (0.25, 0.5, 0.75, 1.0, 1.25):
            yield (f'[[paths]]\nname = "circle-r{radius:g}-v{v:g}"\nshape = "circle"\n'
                   f'radius = {radius}\nlaps = {laps}\npeak_speed = {v}\n')


def main() -> None:
    blocks = [HEAD] + list(pushes()) + list(noise()) + list(envelope())
    OUT.write_text("\n".join(blocks))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
