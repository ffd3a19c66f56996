"""How hard each friction drop of a generated world is for a planner that knows only the
friction under the car (the oracle's information), from the course and the terrain map alone.

    python studies/generalization/friction_drops.py --seeds 100 101 212 [--vehicle ford_escort]

For every place along the course where the friction drops (mu_before -> mu_after), the car
arrives at the friction-limited reference speed of mu_before (``speed_profile`` with the NMPC's
defaults and the scenario's speed cap) and from there brakes with all the friction the bend
leaves on mu_after (the friction circle); the row's number is the largest lateral demand on the
way, v^2 |kappa| / (mu g) over the stretch until the speed is the mu_after profile's. Above 1
the ground cannot hold the car on the course's centre line; below 1 it can. It prints the
three hardest drops per world. A frozen study script: generated worlds are written to a
temporary folder.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from pcvfe_drake.control.nmpc_config import NmpcConfig
from pcvfe_drake.control.speed_profile import speed_profile
from pcvfe_drake.diagrams.world_io import build_world
from pcvfe_drake.vehicle.params import load_vehicle
from pcvfe_drake.worlds.generate import write_generated_world


def hardest_drops(world_file: Path, vehicle: str, v_max: float) -> list[tuple]:
    """(demand, s [m], mu_before, mu_after) of each friction drop along the course, hardest
    first."""
    params = load_vehicle(vehicle)
    world = build_world(world_file, vehicle=params)
    course, cfg = world.course, NmpcConfig()
    mu = np.asarray(world.terrain_map.mu_at(np.column_stack([course.x, course.y])), dtype=float)
    kappa = np.abs(course.curvature)
    profiles: dict[float, np.ndarray] = {}

    def profile(m: float) -> np.ndarray:
        if m not in profiles:
            profiles[m] = speed_profile(
                course,
                m,
                v_max=v_max,
                speed_margin=cfg.speed_margin,
                long_fraction=cfg.long_fraction,
                a_drive_max=params.a_max,
                g=params.g,
            ).v
        return profiles[m]

    drops = []
    for i in np.flatnonzero(mu < np.roll(mu, 1)):
        before, after = float(mu[i - 1]), float(mu[i])
        v, target, demand = float(profile(before)[i - 1]), profile(after), 0.0
        for step in range(course.n):
            j = (i + step) % course.n
            lateral = v * v * kappa[j]
            demand = max(demand, lateral / (mu[j] * params.g))
            if v <= target[j] or mu[j] > after:
                break
            brake = max((mu[j] * params.g) ** 2 - lateral**2, 0.0) ** 0.5
            v = max(v * v - 2.0 * brake * course.ds, 0.0) ** 0.5
        drops.append((demand, float(course.s[i]), before, after))
    return sorted(drops, reverse=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", required=True)
    parser.add_argument("--vehicle", default="ford_escort")
    parser.add_argument("--v-max", type=float, default=12.0, help="speed cap [m/s] (paper_eval)")
    args = parser.parse_args()
    params = load_vehicle(args.vehicle)
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            world_file, _ = write_generated_world(seed, params, out_dir=Path(tmp))
            rows = hardest_drops(world_file, args.vehicle, args.v_max)[:3]
            text = "  ".join(f"{d:.2f} at s={s:.0f} m ({b:.2f}->{a:.2f})" for d, s, b, a in rows)
            print(f"world {seed}: {text}")


if __name__ == "__main__":
    main()
