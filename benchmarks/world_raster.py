"""How long loading a world file and building its terrain raster takes (target: under 1 s).

Times, for the shipped ``paper`` world (300 m x 200 m at 5 cm: 6000 x 4000 cells, four
quadrants and two wavy transition strips): loading the world file (``yaml_load_typed`` and the
checks) plus building its ``TerrainMap`` from the file's regions and strips, against the same
polygons built by ``TerrainMap.from_polygons`` directly (the baseline: what the built-in layout's
raster cost, without a file). Also times a generated world (``pcvfe world generate --seed 0``)
of about the same size. Each figure is the median of repeated builds.

Usage: python benchmarks/world_raster.py [--quick]
Prints one JSON object as its last line.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from pcvfe_drake.diagrams.world_io import load_world
from pcvfe_drake.perception.terrain import Terrain, TerrainMap
from pcvfe_drake.vehicle.params import load_vehicle
from pcvfe_drake.worlds.build import build_terrain_map, strip_polygon
from pcvfe_drake.worlds.generate import write_generated_world

TARGET_S = 1.0


def median_time_s(fn, reps: int) -> float:
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def load_and_build(name_or_path) -> TerrainMap:
    spec, path = load_world(name_or_path)
    return build_terrain_map(spec, path.parent, source=str(path))


def polygons_directly(name: str) -> TerrainMap:
    """The same regions and strips painted by ``TerrainMap.from_polygons`` (no file)."""
    spec, _ = load_world(name)
    terrains = {t.name: Terrain(t.name, t.mu, t.texture) for t in spec.terrains}
    regions = [(terrains[r.terrain], np.asarray(r.polygon, float)) for r in spec.regions]
    regions += [(terrains[s.terrain], strip_polygon(s)) for s in spec.strips]
    x0, x1, y0, y1 = spec.bounds_m

    def build() -> TerrainMap:
        return TerrainMap.from_polygons(regions, bounds_m=(x0, x1, y0, y1), resolution_m=0.05)

    return build


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repetitions")
    args = parser.parse_args()
    reps = 3 if args.quick else 7
    load_and_build("paper")  # imports and caches warmed up
    world_s = median_time_s(lambda: load_and_build("paper"), reps)
    baseline_s = median_time_s(polygons_directly("paper"), reps)
    same = np.array_equal(load_and_build("paper").labels, polygons_directly("paper")().labels)
    with tempfile.TemporaryDirectory() as tmp:
        path, generated = write_generated_world(0, load_vehicle("ford_escort"), Path(tmp))
        spec, _ = load_world(path)
        generated_s = median_time_s(lambda: load_and_build(path), reps)
        x0, x1, y0, y1 = spec.bounds_m
    result = {
        "world": "paper",
        "size_m": [300.0, 200.0],
        "resolution_m": 0.05,
        "load_and_build_s": round(world_s, 4),
        "from_polygons_s": round(baseline_s, 4),
        "ratio_to_from_polygons": round(world_s / baseline_s, 3),
        "same_raster": bool(same),
        "generated_world_size_m": [x1 - x0, y1 - y0],
        "generated_load_and_build_s": round(generated_s, 4),
        "target_s": TARGET_S,
        "meets_target": bool(world_s < TARGET_S),
        "repetitions": reps,
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
