import re

import numpy as np
import pytest
from matplotlib.path import Path

from pcvfe_drake.diagrams.world_io import load_world, world_terrain_map
from pcvfe_drake.perception.ground_render import render_topdown
from pcvfe_drake.perception.terrain import MuField, Terrain, TerrainMap
from pcvfe_drake.perception.texture_library import TextureSet
from pcvfe_drake.worlds.build import strip_polygon


@pytest.fixture(scope="module")
def default_map():
    return world_terrain_map("paper")


def solid_textures(names, colors):
    return TextureSet.from_arrays(
        {n: (np.full((8, 8, 3), c, np.uint8), 1.0) for n, c in zip(names, colors, strict=True)}
    )


def test_default_map_layout_and_public_simulator_mu(default_map):
    m = default_map
    assert m.bounds_m == (-150.0, 150.0, -100.0, 100.0)
    probes = {
        (30.0, 20.0): ("patchy_grass", 0.3),
        (-30.0, 20.0): ("brick", 0.8),
        (-30.0, -20.0): ("sand", 0.45),
        (30.0, -20.0): ("concrete", 0.6),
        (0.0, 30.0): ("gravel", 0.55),
        (0.0, -45.0): ("gravel", 0.55),
        (55.0, 0.0): ("dry_soil", 0.5),
        (-62.0, 0.0): ("dry_soil", 0.5),
        (140.0, 95.0): ("patchy_grass", 0.3),
        (-140.0, -95.0): ("sand", 0.45),
        (0.0, 95.0): ("gravel", 0.55),
        (-145.0, 0.0): ("dry_soil", 0.5),
    }
    xy = np.array(list(probes))
    assert m.name_at(xy).tolist() == [v[0] for v in probes.values()]
    np.testing.assert_allclose(m.mu_at(xy), [v[1] for v in probes.values()])


def test_default_map_strip_width_is_respected(default_map):
    # Strip edges wobble by at most 0.37 m around +-1.5 m (plus up to a 5 cm cell).
    y = np.linspace(-98, 98, 800)
    y = y[np.abs(y) > 3.0]
    for x, expect_gravel in [
        (0.0, True),
        (1.05, True),
        (-1.05, True),
        (1.95, False),
        (-1.95, False),
    ]:
        names = default_map.name_at(np.stack([np.full_like(y, x), y], axis=1))
        assert np.all((names == "gravel") == expect_gravel), x
    # Cross-section along y = 30: strip width in cells is 3 m +- wobble.
    x = np.arange(-5, 5, 0.01)
    names = default_map.name_at(np.stack([x, np.full_like(x, 30.0)], axis=1))
    width = np.count_nonzero(names == "gravel") * 0.01
    assert 2.3 < width < 3.7


def test_a_lap_of_a_course_crosses_every_quadrant_for_a_quarter(default_map):
    # A 260 m x 170 m rectangle (the slalom's size) with rounded corners (a clipped ellipse).
    a, b = 130.0, 85.0
    t = np.linspace(0, 2 * np.pi, 20000, endpoint=False)
    x = np.clip(a * np.cos(t) * 1.3, -a, a)
    y = np.clip(b * np.sin(t) * 1.3, -b, b)
    names = default_map.name_at(np.stack([x, y], axis=1))
    seg = np.hypot(np.diff(x, append=x[0]), np.diff(y, append=y[0]))
    total = seg.sum()
    for name in ("patchy_grass", "brick", "sand", "concrete"):
        share = seg[names == name].sum() / total
        assert 0.2 < share < 0.27, (name, share)


def test_default_map_strips_are_the_cells_whose_centre_is_inside_the_strip_polygon(default_map):
    # Exact point-in-polygon (matplotlib) of each wavy strip's polygon at raster cell centres,
    # against the labels of the paper world (gravel painted over dry soil where they cross).
    res = default_map.resolution_m
    rng = np.random.default_rng(7)
    spec, _ = load_world("paper")
    for strip in spec.strips:
        name, along_x = strip.terrain, strip.start[1] == strip.end[1]
        poly = strip_polygon(strip)
        cols = rng.integers(0, default_map.labels.shape[1], 4000)
        rows = rng.integers(0, default_map.labels.shape[0], 4000)
        if along_x:  # rows near y = 0
            rows = rng.integers(1960, 2040, 4000)
        else:  # columns near x = 0
            cols = rng.integers(2960, 3040, 4000)
        xy = np.stack(
            [default_map.x_min_m + (cols + 0.5) * res, default_map.y_max_m - (rows + 0.5) * res], 1
        )
        inside = Path(poly).contains_points(xy)
        names = default_map.name_at(xy)
        if name == "dry_soil":  # gravel covers it along x ~ 0
            keep = np.abs(xy[:, 0]) > 2.5
            assert np.array_equal(inside[keep], names[keep] == "dry_soil")
        else:
            assert np.array_equal(inside, names == "gravel")
        assert inside.sum() > 500


def test_default_map_raster_is_read_only(default_map):
    assert not default_map.labels.flags.writeable
    assert world_terrain_map("paper_no_strips").names == [
        "patchy_grass",
        "brick",
        "sand",
        "concrete",
    ]


def test_scalar_and_batch_lookups_agree(default_map):
    rng = np.random.default_rng(1)
    xy = rng.uniform([-150, -100], [150, 100], size=(500, 2))
    idx = default_map.index_at(xy)
    assert idx.shape == (500,) and idx.dtype.kind == "i"
    for p, k in zip(xy[:50], idx[:50], strict=True):
        assert default_map.index_at(p) == k
        assert isinstance(default_map.mu_at(p), float)
        assert default_map.name_at(p) == default_map.terrains[k].name


def _cell_edge_points(m: TerrainMap, rng, n: int) -> np.ndarray:
    """Points exactly on cell edges and corners, on the map's border and just beyond it."""
    rows, cols = m.labels.shape
    col = rng.integers(-2, cols + 3, n)
    row = rng.integers(-2, rows + 3, n)
    x = m.x_min_m + col * m.resolution_m
    y = m.y_max_m - row * m.resolution_m
    return np.column_stack([x, y])


@pytest.mark.parametrize("with_field", [False, True])
def test_single_point_lookup_equals_the_batch_lookup(with_field):
    # The plant looks up one point per derivative evaluation through mu_and_index_at_point;
    # it must give the batch look-up's terrain, mu and errors everywhere: inside, on cell
    # edges and corners, on the border, outside, on uncovered cells.
    a, b, void = Terrain("a", 0.5, "ta"), Terrain("b", 0.7, "tb"), Terrain("v", 1.0, "tv")
    rng = np.random.default_rng(3)
    labels = rng.choice(np.array([0, 1, 255], dtype=np.uint8), size=(30, 40), p=[0.45, 0.45, 0.1])
    field = MuField(rng.normal(0, 0.1, (6, 7)), x0_m=-3.0, y0_m=1.0, spacing_m=1.7)
    placement = dict(x_min_m=-2.3, y_min_m=1.1, resolution_m=0.25)
    strict = TerrainMap(
        labels, [a, b], **placement, mu_fields=[field, None] if with_field else None
    )
    lenient = TerrainMap(
        labels,
        [a, b, void],
        **placement,
        outside="v",
        mu_fields=[field, None, None] if with_field else None,
    )
    x0, x1, y0, y1 = strict.bounds_m
    inside = rng.uniform([x0, y0], [x1, y1], size=(400, 2))
    around = rng.uniform([x0 - 2, y0 - 2], [x1 + 2, y1 + 2], size=(400, 2))
    points = np.vstack([inside, around, _cell_edge_points(strict, rng, 400)])
    for m in (strict, lenient):
        for p in points:
            try:
                want_mu, want_k = m.mu_and_index_at(p[None, :])
            except ValueError as exc:
                with pytest.raises(ValueError, match=re.escape(str(exc))):
                    m.mu_and_index_at_point(p[0], p[1])
                continue
            mu, k = m.mu_and_index_at_point(p[0], p[1])
            assert type(mu) is float and type(k) is int
            assert (mu, k) == (float(want_mu[0]), int(want_k[0]))
            assert m.index_at(p) == k and m.mu_at(p) == mu
    for bad in ([np.nan, 2.0], [0.0, np.inf]):
        with pytest.raises(ValueError, match="not finite"):
            strict.mu_and_index_at_point(*bad)


def test_polygon_rasterisation_matches_exact_point_in_polygon():
    grass = Terrain("grass", 0.3, "g")
    rock = Terrain("rock", 0.9, "r")
    tri = np.array([[-3.3, -2.1], [4.7, -1.2], [0.4, 3.9]])
    m = TerrainMap.from_polygons(
        [(grass, np.array([[-5, -5], [5, -5], [5, 5], [-5, 5]])), (rock, tri)],
        bounds_m=(-5, 5, -5, 5),
        resolution_m=0.1,
    )
    rng = np.random.default_rng(0)
    xy = rng.uniform(-4.99, 4.99, size=(20000, 2))
    exact = Path(tri).contains_points(xy)
    got = m.name_at(xy) == "rock"
    # distance to the triangle's edges
    d = np.full(len(xy), np.inf)
    for i in range(3):
        p, q = tri[i], tri[(i + 1) % 3]
        t = np.clip(((xy - p) @ (q - p)) / ((q - p) @ (q - p)), 0, 1)
        d = np.minimum(d, np.linalg.norm(xy - (p + t[:, None] * (q - p)), axis=1))
    far = d > 0.071  # more than half a cell diagonal from an edge
    assert np.array_equal(got[far], exact[far])
    assert np.mean(got != exact) < 0.01


def test_label_image_world_placement():
    a, b = Terrain("a", 0.5, "ta"), Terrain("b", 0.7, "tb")
    labels = np.array([[0, 0, 1], [1, 1, 1]])  # row 0 is north
    m = TerrainMap.from_label_image(labels, [a, b], x_min_m=10.0, y_min_m=-4.0, resolution_m=2.0)
    assert m.bounds_m == (10.0, 16.0, -4.0, 0.0)
    xy = np.array([[10.5, -0.5], [13.9, -1.9], [14.1, -0.5], [10.5, -2.1], [15.9, -3.9]])
    assert m.name_at(xy).tolist() == ["a", "a", "b", "b", "b"]
    np.testing.assert_allclose(m.mu_at(xy), [0.5, 0.5, 0.7, 0.7, 0.7])


def test_outside_and_uncovered_points_raise_or_use_outside_policy():
    a = Terrain("a", 0.5, "ta")
    labels = np.array([[0, 255], [0, 0]])
    m = TerrainMap.from_label_image(labels, [a], x_min_m=0, y_min_m=0, resolution_m=1.0)
    with pytest.raises(ValueError, match=r"\(5.000, 0.500\) m is outside"):
        m.mu_at(np.array([5.0, 0.5]))
    with pytest.raises(ValueError, match=r"outside"):
        m.mu_at(np.array([[0.5, 0.5], [-0.1, 0.5]]))
    with pytest.raises(ValueError, match="no terrain region"):
        m.index_at(np.array([1.5, 1.5]))
    with pytest.raises(ValueError, match="not finite"):
        m.mu_at(np.array([np.nan, 0.5]))
    with pytest.raises(ValueError, match=r"xy\[1\]"):
        m.mu_at(np.array([[0.5, 0.5], [np.inf, 0.5]]))
    with pytest.raises(ValueError, match="shape"):
        m.mu_at(np.zeros((3, 3)))
    m2 = TerrainMap.from_label_image(
        labels,
        [a, Terrain("void", 1.0, "tv")],
        x_min_m=0,
        y_min_m=0,
        resolution_m=1.0,
        outside="void",
    )
    assert m2.name_at(np.array([[5.0, 0.5], [1.5, 1.5], [0.5, 0.5]])).tolist() == [
        "void",
        "void",
        "a",
    ]


def test_bad_construction_inputs_are_named():
    a = Terrain("a", 0.5, "ta")
    with pytest.raises(ValueError, match="mu must be"):
        Terrain("x", -0.1, "t")
    with pytest.raises(ValueError, match=r"values \[3\]"):
        TerrainMap(np.array([[0, 3]]), [a], x_min_m=0, y_min_m=0, resolution_m=1)
    with pytest.raises(ValueError, match="unique"):
        TerrainMap(np.array([[0]]), [a, a], x_min_m=0, y_min_m=0, resolution_m=1)
    with pytest.raises(ValueError, match="integer dtype"):
        TerrainMap(np.array([[0.0]]), [a], x_min_m=0, y_min_m=0, resolution_m=1)
    with pytest.raises(ValueError, match="outside terrain 'zz'"):
        TerrainMap(np.array([[0]]), [a], x_min_m=0, y_min_m=0, resolution_m=1, outside="zz")
    with pytest.raises(ValueError, match=r"region 0 \(a\)"):
        TerrainMap.from_polygons([(a, np.zeros((2, 2)))], bounds_m=(0, 1, 0, 1))
    with pytest.raises(ValueError, match="two different terrains"):
        TerrainMap.from_polygons(
            [(a, np.eye(3)[:, :2]), (Terrain("a", 0.9, "tb"), np.eye(3)[:, :2])],
            bounds_m=(0, 1, 0, 1),
        )


def test_topdown_render_shows_each_terrain_where_the_map_has_it(default_map):
    names = [t.texture for t in default_map.terrains]
    colors = [
        (40, 160, 40),
        (170, 60, 40),
        (220, 200, 150),
        (150, 150, 150),
        (120, 90, 60),
        (90, 90, 100),
    ]
    textures = solid_textures(names, colors)
    img = render_topdown(default_map, 2.0, textures=textures)
    assert img.shape == (400, 600, 3) and img.dtype == np.uint8
    # pixel (col, row) <-> world (x_min + (c + .5)/2, y_max - (r + .5)/2)
    rng = np.random.default_rng(3)
    rc = rng.integers([0, 0], [400, 600], size=(400, 2))
    xy = np.stack([-150 + (rc[:, 1] + 0.5) / 2, 100 - (rc[:, 0] + 0.5) / 2], axis=1)
    idx = default_map.index_at(xy)
    # compare away from boundaries (where colours blend)
    near = (np.abs(xy[:, 0]) < 3) | (np.abs(xy[:, 1]) < 3)
    expected = np.array(colors)[idx]
    got = img[rc[:, 0], rc[:, 1]].astype(int)
    assert np.abs(got[~near] - expected[~near]).max() <= 1
    flat = render_topdown(default_map, 1.0, flat=True, textures=textures)
    assert flat.shape == (200, 300, 3)
    assert tuple(flat[70, 210]) == colors[0]  # x = 60.5, y = 29.5 -> patchy grass


def test_paper_world_terrains_are_the_public_simulator_values(default_map):
    t = {terrain.name: terrain for terrain in default_map.terrains}
    assert {n: t[n].mu for n in ("patchy_grass", "brick", "sand", "concrete")} == {
        "patchy_grass": 0.3,
        "brick": 0.8,
        "sand": 0.45,
        "concrete": 0.6,
    }


def test_cli_terrain_map_writes_the_figure(tmp_path, capsys):
    import cv2

    from pcvfe_drake.cli import main

    out = tmp_path / "map.png"
    assert main(["terrain-map", "--out", str(out), "--px-per-m", "1", "--flat"]) == 0
    img = cv2.imread(str(out))
    assert img.shape == (200, 300, 3)
    text = capsys.readouterr().out
    assert "patchy_grass   mu 0.30" in text and "brick          mu 0.80" in text
