"""The designer's GLB (tests/support/assets_util.write_designer_glb: a plastic floor with an sRGB
stripes texture, a gold ggx sphere and a red plastic sphere, with the file's vertex normals) in
the lighting bake and the view bake: both take the textured plastic, and their unbiased frames
agree with ``mis`` of the same changed scene (the map turned; another eye) within the standard
errors, per 4 x 4 block of pixels and channel and over the whole frame. The kernels' frames
equal their numpy twins' on the same random numbers."""
from __future__ import annotations

import numpy as np
import pytest

import wavlight
from assets_util import designer_scene, write_designer_glb
from scenes_util import write_raw_image
from wavlight.relight import view_frames
from wavlight.relight.converge import converge

SIZE = 24
EYE, TARGET = [1.2, 1.3, 2.2], [0.0, 0.4, 0.0]


def block_z(image, stderr, ref):
    """z of each 4 x 4 block and channel, and of the whole frame, of ``image`` - ``ref``."""
    var = stderr.astype(np.float64) ** 2 + ref.stderr.astype(np.float64) ** 2
    n = SIZE // 4
    diff = (image.astype(np.float64) - ref.image).reshape(n, 4, n, 4, 3).sum(axis=(1, 3))
    z = diff / np.sqrt(var.reshape(n, 4, n, 4, 3).sum(axis=(1, 3)))
    return z, (image.astype(np.float64) - ref.image).sum() / np.sqrt(var.sum())


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """The GLB and a sky with a bright patch (highlights on the coat and on the gold)."""
    folder = tmp_path_factory.mktemp("designer_bakes")
    rng = np.random.default_rng(7)
    sky = (np.linspace(2.0, 0.2, 32)[:, None, None] * np.ones((32, 64, 3))
           * rng.uniform(0.7, 1.3, (32, 64, 3))).astype(np.float32)
    sky[5:8, 38:42] = 30.0
    write_raw_image(folder / "sky.exr", sky)
    write_designer_glb(folder / "d.glb")
    return folder


def scene_of(folder, rotate_y=20.0, camera=None):
    d = designer_scene(folder / "d.glb", folder / "sky.exr", SIZE, SIZE)
    d["environment"]["rotate_y"] = rotate_y
    if camera is not None:
        d["camera"] = camera
    return wavlight.load_dict(d, base_dir=folder)


def test_the_scene_is_textured_plastic(folder, device):
    scene = scene_of(folder)
    kinds = {m.name.split(":")[-1]: m.kind for m in scene.materials}
    assert scene.textured
    assert sum(k == wavlight.bsdfs.PLASTIC for k in kinds.values()) == 2, kinds


@pytest.mark.slow
def test_lighting_bake_unbiased_frame_equals_mis(folder, device):
    """The lighting bake (the coat's transfer stored beside the albedo's) turned 60 degrees."""
    scene = scene_of(folder)
    tr = wavlight.bake(scene, spp=4, levels=4, terms=256, priority="area", tolerance=1e-4, bits=16)
    assert tr.header["coat"]
    r = converge(tr, scene, rotate_y=80.0, spp=64, seed=3)
    ref = wavlight.render_full(scene_of(folder, rotate_y=80.0), spp=512, strategy="mis", seed=11)
    z, total = block_z(r.image, r.stderr, ref)
    assert np.abs(z).max() < 4.0, z
    assert abs(total) < 3.3, total
    twin = converge(tr, scene, rotate_y=80.0, spp=4, seed=5, backend="numpy")
    kern = converge(tr, scene, rotate_y=80.0, spp=4, seed=5)
    assert abs((kern.image - twin.image).sum()) < 0.5 * np.sqrt((twin.stderr.astype(np.float64) ** 2).sum())


@pytest.mark.slow
def test_view_bake_unbiased_frame_equals_mis(folder, tmp_path, device):
    """The view bake (plastic's two walks; the albedo times the texture at the hit) seen from
    another eye: the unbiased frame against mis there, and the two backends' frames."""
    scene = scene_of(folder)
    tr = wavlight.bake(scene, tmp_path / "v.wlt", vary="view", levels=4, density=400, tolerance=1e-3, bits=16)
    frames = view_frames.ViewFrames(tr, scene)
    r = frames.converge(EYE, TARGET, spp=64, seed=3)
    moved = scene_of(folder, camera={"eye": EYE, "target": TARGET, "fov_y": 40.0})
    ref = wavlight.render_full(moved, spp=1024, strategy="mis", seed=11)
    z, total = block_z(r.image, r.stderr, ref)
    assert np.abs(z).max() < 4.0, z
    assert abs(total) < 3.3, total
    for mode in view_frames.MODES:
        a, _ = frames.frame(EYE, TARGET, 32, 32, mode=mode)
        b, _ = frames.frame(EYE, TARGET, 32, 32, mode=mode, backend="numpy")
        close = np.abs(a - b) <= 1e-3 * np.abs(b) + 1e-5
        assert close.mean() > 0.99, (mode, close.mean())
