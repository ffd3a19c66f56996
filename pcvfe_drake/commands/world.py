"""``pcvfe world``: generate a world from a seed, or draw a world (docs/worlds.md).

The world loader (pydrake's ``yaml_load_typed``) is imported inside the commands, so importing
this module (and the CLI) does not import pydrake.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pcvfe_drake.runs.output_paths import check_output_dir, check_output_file


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "world",
        help="generate a random world from a seed, or draw a world file",
        description=(
            "Worlds are data (docs/worlds.md). 'generate' writes a world file and its course "
            "file from a seed: a random drivable closed course, 3 to 6 terrain regions it crosses "
            "in a random order, each a shipped texture with a friction drawn from a range, and "
            "transition strips; the same seed gives the same files. 'show' draws a world."
        ),
    )
    sub = parser.add_subparsers(dest="world_command", metavar="ACTION")
    gen = sub.add_parser("generate", help="write a generated world (world + course file)")
    gen.add_argument("--seed", type=int, required=True, help="seed of every random choice")
    gen.add_argument(
        "--terrains", type=int, default=None, help="terrain regions (3-6; default: drawn)"
    )
    gen.add_argument(
        "--mu-range",
        type=float,
        nargs=2,
        default=None,
        metavar=("LO", "HI"),
        help="range of the drawn frictions (default 0.15 1.0)",
    )
    gen.add_argument(
        "--vehicle",
        default="ford_escort",
        help="vehicle preset or file the course must be drivable by (its size "
        "also scales the world)",
    )
    gen.add_argument("--out", type=Path, default=Path("."), help="folder for the files")
    gen.add_argument("--name", default=None, help="world name (default generated_sNNNN)")
    gen.set_defaults(func=run_generate)
    show = sub.add_parser("show", help="draw a world: regions by terrain with mu, course, start")
    show.add_argument("world", help="world file or shipped world name")
    show.add_argument("--out", type=Path, default=Path("world.png"), help="PNG file")
    show.set_defaults(func=run_show)
    parser.set_defaults(func=lambda args: (parser.print_help(), 2)[1])


def run_generate(args: argparse.Namespace) -> int:
    from pcvfe_drake.diagrams.world_io import build_world
    from pcvfe_drake.vehicle.params import load_vehicle
    from pcvfe_drake.worlds.generate import MU_RANGE, write_generated_world

    check_output_dir(args.out)
    vehicle = load_vehicle(args.vehicle)
    mu_range = tuple(args.mu_range) if args.mu_range else MU_RANGE
    name = args.name or f"generated_s{args.seed:04d}"
    print(f"generating world {name} (seed {args.seed}, vehicle {vehicle.name}) ...", flush=True)
    world_path, world = write_generated_world(
        args.seed, vehicle, args.out, terrains=args.terrains, mu_range=mu_range, name=name
    )
    built = build_world(world_path, vehicle=vehicle)  # the checks every world passes
    x0, x1, y0, y1 = built.terrain_map.bounds_m
    print(
        f"  {world_path}: {x1 - x0:g} m x {y1 - y0:g} m, course {built.course.name} "
        f"({world.lap_m:.0f} m lap)"
    )
    regions, strip = world.terrains[:-1], world.terrains[-1]
    print(
        "  terrains along the course: "
        + ", ".join(f"{n} (mu {m:.2f})" for n, m in regions)
        + f"; transition strips: {strip[0]} (mu {strip[1]:.2f})"
    )
    print(
        f"  run it: printf 'world: {world_path.resolve()}\\n' > with_world.yaml; "
        "pcvfe simulate --with with_world.yaml"
    )
    return 0


def run_show(args: argparse.Namespace) -> int:
    from pcvfe_drake.control.course import load_course
    from pcvfe_drake.diagrams.world_io import load_world, world_course_name
    from pcvfe_drake.worlds.build import build_terrain_map
    from pcvfe_drake.worlds.figure import world_figure

    check_output_file(args.out)
    if args.out.suffix.lower() != ".png":
        print(f"pcvfe world show: --out {args.out}: give a .png file", file=sys.stderr)
        return 2
    spec, world_path = load_world(args.world)
    terrain_map = build_terrain_map(spec, world_path.parent, source=str(world_path))
    course_name = world_course_name(spec, world_path)
    course = load_course(course_name) if course_name else None
    title = f"{spec.name}: {spec.description}" if spec.description else spec.name
    path = world_figure(terrain_map, course, title, args.out)
    print(f"{spec.name} ({world_path}) -> {path}")
    return 0
