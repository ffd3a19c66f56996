import importlib.util

import numpy as np
import pytest

from pcvfe_drake.diagrams.world_io import load_world
from pcvfe_drake.perception.texture_library import TextureSet, read_index, textures_dir
from pcvfe_drake.worlds.world_file import shipped_worlds


def load_script():
    path = textures_dir() / "make_textures.py"
    spec = importlib.util.spec_from_file_location("make_textures", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_index_lists_at_least_ten_square_rgb_textures():
    entries = read_index(textures_dir())
    assert len(entries) >= 10
    textures = TextureSet()
    for e in entries:
        img = textures.image(e.name)
        assert img.dtype == np.uint8 and img.shape[2] == 3
        assert img.shape[0] == img.shape[1] >= 512
        assert 0 < e.mu <= 1.5 and e.tile_m > 0 and e.provenance and e.method
    # the shipped worlds' terrains all have a shipped texture
    for name in shipped_worlds():
        for t in load_world(name)[0].terrains:
            textures.entry(t.texture)


def test_textures_tile_without_seams():
    textures = TextureSet()
    for name in textures.names:
        img = textures.image(name).astype(float)
        inner = np.mean(np.abs(np.diff(img, axis=1)))  # typical neighbour difference
        seam_x = np.mean(np.abs(img[:, 0] - img[:, -1]))
        seam_y = np.mean(np.abs(img[0] - img[-1]))
        inner_y = np.mean(np.abs(np.diff(img, axis=0)))
        assert seam_x < 1.6 * inner + 2, (name, seam_x, inner)
        assert seam_y < 1.6 * inner_y + 2, (name, seam_y, inner_y)


def test_textures_are_distinct_in_colour_or_texture():
    textures = TextureSet()
    names = textures.names
    means = np.array([textures.mean_rgb(n) for n in names])
    stds = np.array([textures.image(n).reshape(-1, 3).std(axis=0) for n in names])
    sig = np.hstack([means, stds])
    d = np.linalg.norm(sig[:, None] - sig[None], axis=2)
    np.fill_diagonal(d, np.inf)
    assert d.min() > 10.0


def test_regeneration_is_identical():
    # Regenerates every texture in memory and compares pixels with the committed PNGs, the
    # index text, and the encoded bytes of one PNG (a full rewrite is `make_textures.py --out`).
    script = load_script()
    images = script.make_all()
    textures = TextureSet()
    assert sorted(images) == sorted(textures.names)
    for name, img in images.items():
        assert np.array_equal(img, textures.image(name)), name
    folder = textures_dir()
    assert script.index_yaml() == (folder / "index.yaml").read_text()
    import cv2

    ok, png = cv2.imencode(
        ".png", cv2.cvtColor(images["mud"], cv2.COLOR_RGB2BGR), script.PNG_PARAMS
    )
    assert ok and png.tobytes() == (folder / "mud.png").read_bytes()


def test_loader_errors_name_the_problem(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="unknown texture 'lava'"):
        TextureSet().image("lava")
    (tmp_path / "index.yaml").write_text("textures:\n  - name: a\n    file: a.png\n")
    with pytest.raises(ValueError, match="entry 0 is malformed"):
        TextureSet(tmp_path)
    (tmp_path / "index.yaml").write_text(
        "textures:\n  - {name: a, file: a.png, mu: 1, tile_m: 1}\n"
    )
    with pytest.raises(FileNotFoundError, match="a.png"):
        TextureSet(tmp_path).image("a")
    (tmp_path / "a.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match="could not be decoded"):
        TextureSet(tmp_path).image("a")
    monkeypatch.setenv("PCVFE_TEXTURES_DIR", str(tmp_path))
    assert textures_dir() == tmp_path
