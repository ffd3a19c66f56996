"""Generated worlds: byte-identical per seed, drivable, crossing their terrains; the CLI's
``world generate`` and ``world show``."""

from __future__ import annotations

import numpy as np
import pytest

from pcvfe_drake.cli import main
from pcvfe_drake.perception.texture_library import default_textures
from pcvfe_drake.vehicle.params import load_vehicle
from pcvfe_drake.worlds.generate import generate_world


def test_the_same_seed_gives_the_same_files_byte_for_byte(tmp_path):
    textures = default_textures().names
    car = load_vehicle("ford_escort")
    a = generate_world(5, car, textures=textures)
    b = generate_world(5, car, textures=textures)
    assert a.world_yaml == b.world_yaml and a.course_yaml == b.course_yaml
    c = generate_world(6, car, textures=textures)
    assert c.world_yaml != a.world_yaml
    for out in ("one", "two"):
        assert (
            main(
                [
                    "world",
                    "generate",
                    "--seed",
                    "5",
                    "--vehicle",
                    "roboracer",
                    "--out",
                    str(tmp_path / out),
                ]
            )
            == 0
        )
    for name in ("generated_s0005.yaml", "generated_s0005_course.yaml"):
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "two" / name).read_bytes()
    small = generate_world(5, load_vehicle("roboracer"), textures=textures)
    assert (tmp_path / "one" / "generated_s0005.yaml").read_text() == small.world_yaml


@pytest.mark.parametrize("seed", [0, 11])
def test_a_generated_world_is_drivable_and_its_course_crosses_every_region(tmp_path, seed):
    from pcvfe_drake.diagrams.world_io import build_world

    car = load_vehicle("roboracer")  # a small car: a small world, built quickly
    g = generate_world(
        seed, car, terrains=4, mu_range=(0.2, 0.9), textures=default_textures().names
    )
    (tmp_path / f"generated_s{seed:04d}_course.yaml").write_text(g.course_yaml)
    (tmp_path / "w.yaml").write_text(g.world_yaml)
    world = build_world(tmp_path / "w.yaml", vehicle=car)  # bounds, coverage, turning radius
    m, course = world.terrain_map, world.course
    assert len(world.spec.regions) == 4 and m.transitions == (g.terrains[-1][0],)
    assert all(0.2 <= t.mu <= 0.9 for t in m.terrains)
    names = m.name_at(np.column_stack([course.x, course.y]))
    stretches = [n for i, n in enumerate(names) if i == 0 or n != names[i - 1]]
    regions = [n for n in stretches if n not in m.transitions]
    # Each region is one stretch of the lap, in the order the file lists them (cyclically).
    order = [r.terrain for r in world.spec.regions]
    assert sorted(set(regions)) == sorted(order)
    k = order.index(regions[0])
    assert [n for i, n in enumerate(regions) if i == 0 or n != regions[i - 1]][:4] == (
        order[k:] + order[:k]
    )
    on_region = np.isin(names, order)
    assert np.count_nonzero(on_region) > 0.9 * names.size


def test_generate_and_show_from_the_cli(tmp_path, capsys):
    assert (
        main(
            [
                "world",
                "generate",
                "--seed",
                "2",
                "--terrains",
                "3",
                "--vehicle",
                "roboracer",
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "generated_s0002.yaml" in out and "terrains along the course" in out
    png = tmp_path / "w.png"
    assert main(["world", "show", str(tmp_path / "generated_s0002.yaml"), "--out", str(png)]) == 0
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert (
        main(["world", "generate", "--seed", "2", "--terrains", "9", "--out", str(tmp_path)]) == 2
    )
    assert "--terrains must be an integer in [3, 6], got 9" in capsys.readouterr().err
    assert main(["world", "generate", "--seed", "2", "--mu-range", "0.5", "0.1"]) == 2
    assert "--mu-range must satisfy 0 < LO <= HI <= 2" in capsys.readouterr().err
