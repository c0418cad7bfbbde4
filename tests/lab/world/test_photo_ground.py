"""Ground from a real aerial photograph: renders, mean colour, mirror, determinism, detail,
config errors (a small photo generated in tmp_path; the shared photos when present)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from eaglemission.lab.world.ground_images import GroundImageError, ground_image_files
from eaglemission.lab.world.photo_ground import gradient_energy
from eaglemission.lab.world.render import SyntheticWorld
from eaglemission.lab.world.synthetic import GroundImageConfig, SyntheticWorldConfig
from pydantic import ValidationError

from eaglemission.geometry import CameraModel, CameraMount, euler_to_quat

SHARED_PHOTOS = Path(__file__).parents[3] / ".." / "shared" / "data" / "aerial_ground"
Q_LEVEL = euler_to_quat(0.0, 0.0, 0.0)


def _photo(tmp_path: Path, m_per_px: float = 0.05, size: int = 256) -> Path:
    """A smooth random colour field (patches of ~8 px)."""
    rng = np.random.RandomState(4)
    small = rng.randint(40, 200, (size // 8, size // 8, 3)).astype(np.uint8)
    img = cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC)
    path = tmp_path / "ground.png"
    cv2.imwrite(str(path), img)
    path.with_suffix(".yaml").write_text(f"m_per_px: {m_per_px}\n")
    return path


def _nadir(cid: str = "wide") -> CameraModel:
    return CameraModel.from_lens(cid, focal_length_mm=2.8,
                                 mount=CameraMount(0.0, -90.0, 0.0, (0.0, 0.0, 0.0)))


def _world(path: Path, target_config, *, detail: bool = True, seed: int = 1) -> SyntheticWorld:
    sim = SyntheticWorldConfig(seed=seed, ground_image=GroundImageConfig(path=str(path),
                                                                          detail=detail),
                               noise_sigma=0.0, target_north_m=300.0)
    return SyntheticWorld(sim, target_config, extent_m=200.0)


def test_photo_ground_renders_with_the_photos_mean_colour(tmp_path, target_config):
    path = _photo(tmp_path)
    world = _world(path, target_config)
    img, _ = world.render(_nadir(), (0.0, 0.0, -10.0), Q_LEVEL, 1_000_000_000)
    assert img.std() > 5.0
    photo_mean = cv2.imread(str(path)).reshape(-1, 3).mean(axis=0)
    assert np.abs(img.reshape(-1, 3).mean(axis=0) - photo_mean).max() < 20.0


def test_mirrored_beyond_the_edge_is_continuous(tmp_path, target_config):
    path = _photo(tmp_path)  # 12.8 m square: its eastern edge at east = 6.4 m
    world = _world(path, target_config, detail=False)
    img, _ = world.render(_nadir(), (0.0, 6.4, -4.0), Q_LEVEL, 1_000_000_000)
    g = img.astype(np.float32).mean(axis=2)
    # across the image the edge runs through the centre column; no step there
    col = img.shape[1] // 2
    step = np.abs(g[:, col + 1] - g[:, col - 1]).mean()
    typical = np.abs(g[:, 10:-10:7][:, 1:] - g[:, 10:-10:7][:, :-1]).mean() / 7.0 * 2.0
    assert step <= 3.0 * typical + 1.0
    # and it is a mirror: the columns either side of the edge agree
    assert np.abs(g[:, col - 40] - g[:, col + 40]).mean() < 6.0
    # far beyond the photo (5 photo widths) the ground still shows the photo
    far, _ = world.render(_nadir(), (0.0, 70.0, -10.0), Q_LEVEL, 1_000_000_000)
    assert far.std() > 5.0


def test_photo_ground_is_deterministic_with_a_seed(tmp_path, target_config):
    path = _photo(tmp_path)
    pos = (1.0, 2.0, -2.0)
    a, _ = _world(path, target_config, seed=5).render(_nadir(), pos, Q_LEVEL, 7)
    b, _ = _world(path, target_config, seed=5).render(_nadir(), pos, Q_LEVEL, 7)
    c, _ = _world(path, target_config, seed=6).render(_nadir(), pos, Q_LEVEL, 7)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)  # the detail layer follows the seed


def test_detail_layer_restores_contrast_at_the_camera_scale(tmp_path, target_config):
    path = _photo(tmp_path)
    model = _nadir()
    pos = (0.5, 0.5, -0.008 * float(model.K[0, 0]))  # 8 mm per pixel
    native = gradient_energy(cv2.imread(str(path)))
    plain, _ = _world(path, target_config, detail=False).render(model, pos, Q_LEVEL, 7)
    rich, _ = _world(path, target_config).render(model, pos, Q_LEVEL, 7)
    ratio_plain = gradient_energy(plain) / native
    ratio_rich = gradient_energy(rich) / native
    assert ratio_plain < 0.25  # the upsampled photo alone is a blur
    assert ratio_rich > 2.0 * ratio_plain  # the real photo's bound: below


@pytest.mark.skipif(not SHARED_PHOTOS.is_dir(), reason="../shared/data/aerial_ground absent")
def test_detail_ratio_on_a_real_photo_is_above_half(target_config):
    path = SHARED_PHOTOS / "garfield_park" / "IMG_161122_164150_0091_RGB.jpg"
    model = _nadir()
    pos = (3.0, -4.0, -0.008 * float(model.K[0, 0]))  # 8 mm per pixel (wide, near the target)
    native = gradient_energy(cv2.imread(str(path)))
    plain, _ = _world(path, target_config, detail=False).render(model, pos, Q_LEVEL, 7)
    rich, _ = _world(path, target_config).render(model, pos, Q_LEVEL, 7)
    assert gradient_energy(plain) / native < 0.25
    assert gradient_energy(rich) / native > 0.5


def test_target_and_its_shadow_are_drawn_on_the_photo(tmp_path, target_config):
    path = _photo(tmp_path)
    sim = SyntheticWorldConfig(seed=2, ground_image=GroundImageConfig(path=str(path)),
                               noise_sigma=0.0, target_north_m=0.0, target_east_m=0.0)
    world = SyntheticWorld(sim, target_config, extent_m=60.0)
    img, truth = world.render(_nadir(), (0.0, 0.0, -3.0), Q_LEVEL, 1_000_000_000)
    assert truth.target_visible
    top = np.all(img == np.asarray(world.target_top_colour_bgr, np.uint8), axis=2)
    assert top.sum() > 100
    poly = world.shadow_polygon_ned(world.target_object.faces, *world.target_object.pose_ned(0))
    assert poly is not None  # the sun casts a shadow on the photo ground too


def test_config_errors_name_the_file(tmp_path):
    with pytest.raises(ValidationError, match="not found"):
        GroundImageConfig(path=str(tmp_path / "missing.jpg"))
    path = _photo(tmp_path)
    path.with_suffix(".yaml").write_text("m_per_px: -1\n")
    with pytest.raises(ValidationError, match="ground.yaml: m_per_px must be"):
        GroundImageConfig(path=str(path))
    assert GroundImageConfig(path=str(path), m_per_px=0.03).m_per_px == 0.03
    path.with_suffix(".yaml").unlink()
    with pytest.raises(GroundImageError, match="ground.yaml: missing"):
        ground_image_files(tmp_path)


@pytest.mark.skipif(not SHARED_PHOTOS.is_dir(), reason="../shared/data/aerial_ground absent")
def test_the_shared_sites_are_valid_ground_image_folders():
    for site in ("garfield_park", "brighton_beach"):
        files = ground_image_files(SHARED_PHOTOS / site)
        assert len(files) == 6
