import numpy as np
import pytest

from pcvfe_drake.diagrams.world_io import world_terrain_map
from pcvfe_drake.perception.camera import CameraConfig, DownwardCamera
from pcvfe_drake.perception.terrain import Terrain, TerrainMap
from pcvfe_drake.perception.texture_library import TextureSet

BLUE, RED = (20, 40, 220), (220, 30, 30)


@pytest.fixture(scope="module")
def m():
    return world_terrain_map("paper")


def half_plane_map():
    """x < 0: 'blue' terrain, x >= 0: 'red' terrain, 10 cm cells."""
    labels = np.zeros((200, 400), np.uint8)
    labels[:, 200:] = 1
    terrains = [Terrain("blue", 0.4, "blue"), Terrain("red", 0.8, "red")]
    return TerrainMap.from_label_image(labels, terrains, x_min_m=-20, y_min_m=-10, resolution_m=0.1)


def solid(c):
    return np.full((16, 16, 3), c, np.uint8)


def ramp_texture(size=64):
    """Smooth periodic texture so bilinear sampling is nearly exact."""
    t = np.arange(size) / size * 2 * np.pi
    r = 128 + 100 * np.sin(t)[None, :] * np.ones((size, 1))
    g = 128 + 100 * np.cos(t)[:, None] * np.ones((1, size))
    b = 128 + 60 * np.sin(t[:, None] + t[None, :])
    return np.clip(np.stack([r, g, b], axis=2), 0, 255).astype(np.uint8)


def test_default_camera_is_224_square_and_centre_pixel_is_under_the_car():
    cam = DownwardCamera(
        half_plane_map(),
        textures=TextureSet.from_arrays({"blue": (solid(BLUE), 1.0), "red": (solid(RED), 1.0)}),
    )
    assert cam.shape == (224, 224, 3)
    a = cam.pixel_to_world(3.0, -2.0, 0.7)
    centre = a @ [111.5, 111.5, 1.0]
    np.testing.assert_allclose(centre, [3.0, -2.0], atol=1e-12)
    # the top-centre pixel is ahead along the heading, the right-centre pixel to the right
    top = a @ [111.5, 0.0, 1.0] - centre
    right = a @ [223.0, 111.5, 1.0] - centre
    h = 111.5 * cam.config.m_per_px
    np.testing.assert_allclose(top, h * np.array([np.cos(0.7), np.sin(0.7)]), atol=1e-12)
    np.testing.assert_allclose(right, h * np.array([np.sin(0.7), -np.cos(0.7)]), atol=1e-12)
    assert cam.config.footprint_width_m == pytest.approx(2 * np.tan(np.pi / 6))


def test_boundary_appears_where_geometry_puts_it():
    textures = TextureSet.from_arrays({"blue": (solid(BLUE), 1.0), "red": (solid(RED), 1.0)})
    cam = DownwardCamera(half_plane_map(), textures=textures)
    m = cam.config.m_per_px
    # Facing east at x = -0.2 m: the boundary x = 0 is 0.2 m ahead, i.e. rows above the centre.
    img = cam.render(-0.2, 0.0, 0.0)
    is_red = np.all(img == RED, axis=2)
    is_blue = np.all(img == BLUE, axis=2)
    assert np.all(is_red | is_blue)
    boundary_row = 111.5 - 0.2 / m
    rows = np.arange(224)
    assert np.all(is_red[rows < boundary_row - 1.0])
    assert np.all(is_blue[rows > boundary_row + 1.0])
    # Facing north at x = +0.3 m: the boundary runs vertically, left of the centre (west).
    img = cam.render(0.3, 0.0, np.pi / 2)
    boundary_col = 111.5 - 0.3 / m
    cols = np.arange(224)
    red = np.all(img == RED, axis=2)
    assert np.all(red[:, cols > boundary_col + 1.0])
    assert not np.any(red[:, cols < boundary_col - 1.0])


def test_texture_is_sampled_at_the_right_world_points_and_rotates_with_heading():
    tex = ramp_texture()
    tile_m = 0.8
    textures = TextureSet.from_arrays({"blue": (tex, tile_m), "red": (tex, tile_m)})
    cam = DownwardCamera(
        half_plane_map(), CameraConfig(width_px=64, height_px=64), textures=textures
    )
    img = cam.render(-5.0, 1.0, 0.4).astype(float)
    a = cam.pixel_to_world(-5.0, 1.0, 0.4)
    rc = np.array([[5, 7], [32, 32], [60, 10], [18, 50]])
    s = tex.shape[1] / tile_m
    for r, c in rc:
        x, y = a @ [c, r, 1.0]
        u, v = (x * s) % 64, (-y * s) % 64
        expected = tex[int(round(v)) % 64, int(round(u)) % 64].astype(float)
        assert np.abs(img[r, c] - expected).max() < 12, (r, c)
    # Turning the car by +90 degrees rotates the view; the ground image turns clockwise.
    img90 = cam.render(-5.0, 1.0, 0.4 + np.pi / 2).astype(float)
    assert np.abs(np.rot90(img90, k=1) - img).mean() < 2.0
    assert np.abs(img90 - img).mean() > 10.0


def test_default_map_views_show_their_terrain_texture(m):
    textures = TextureSet()
    cam = DownwardCamera(m, textures=textures)
    for xy, name in [
        ((30, 20), "patchy_grass"),
        ((-30, 20), "brick"),
        ((-30, -20), "sand"),
        ((30, -20), "concrete"),
        ((0, 30), "gravel"),
        ((40, 0), "dry_soil"),
    ]:
        img = cam.render(xy[0], xy[1], 0.3)
        mean = img.reshape(-1, 3).mean(axis=0)
        others = {t.name: np.linalg.norm(textures.mean_rgb(t.texture) - mean) for t in m.terrains}
        assert min(others, key=others.get) == name


def test_effects_are_seeded_and_grow_with_speed(m):
    cfg = CameraConfig(exposure_s=0.004, exposure_jitter=0.1, noise_std=5.0)
    cam = DownwardCamera(m, cfg)
    a = cam.render(30, 20, 0.3, 8.0, np.random.default_rng(7))
    b = cam.render(30, 20, 0.3, 8.0, np.random.default_rng(7))
    c = cam.render(30, 20, 0.3, 8.0, np.random.default_rng(8))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    with pytest.raises(ValueError, match="pass rng"):
        cam.render(30, 20, 0.3, 8.0)

    def vertical_detail(img):  # blur runs along image rows (the forward axis)
        return np.abs(np.diff(img.astype(float).mean(axis=2), axis=0)).mean()

    blur_only = DownwardCamera(m, CameraConfig(exposure_s=0.004))
    details = [
        vertical_detail(blur_only.render(30, 20, 0.3, v, np.random.default_rng(0)))
        for v in (0.0, 4.0, 12.0)
    ]
    assert details[0] > details[1] > details[2]
    noisy = DownwardCamera(m, CameraConfig(noise_std=10.0))
    clean = DownwardCamera(m).render(-30, -20, 0.0).astype(float)
    diff = noisy.render(-30, -20, 0.0, 0.0, np.random.default_rng(1)).astype(float) - clean
    assert 8.5 < diff.std() < 11.0


def test_render_state_and_bad_inputs(m):
    cam = DownwardCamera(m)
    x = np.array([30.0, 20.0, 0.0, 5.0, 0.3, 0.0, 0.0])
    assert np.array_equal(cam.render_state(x), cam.render(30.0, 20.0, 0.3))
    with pytest.raises(ValueError, match="outside the terrain map"):
        cam.render(500.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="psi_rad"):
        cam.render(0.0, 0.0, np.nan)
    with pytest.raises(ValueError, match=r"shape \(7,\)"):
        cam.render_state(np.zeros(6))
    with pytest.raises(ValueError, match="fov_deg"):
        CameraConfig(fov_deg=0.0)
    # near the edge of the map the part beyond it (behind the car: the lower rows) is black
    edge = cam.render(m.x_min_m + 0.1, 0.0, 0.0)
    assert np.all(edge[140:] == 0) and edge[:100].mean() > 20
