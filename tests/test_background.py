"""What camera rays that miss see (wavlight.options.BACKGROUND): the map's nearest texel, its
bilinear filter (wavlight.envmap.bilinear, kernels/sphere.h env_bilinear) that wraps in u and is
clamped in v, or nothing (none: misses contribute 0). The filter against its definition, the kernels (shade_rays, converge_shade,
frame_background_bilinear) against their numpy twins, the lighting left as it was, and the
option's scene key and flags."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

import wavlight
from wavlight.envmap import Environment, bilinear


def _map(h=8, w=16, seed=1):
    return np.random.default_rng(seed).uniform(0.1, 5.0, (h, w, 3)).astype(np.float32)


def _dict(pixels, rotate_y=37.0, **env):
    return {"render": {"width": 24, "height": 20, "spp": 4},
            "camera": {"eye": [0.0, 0.0, 3.0], "target": [0.0, 0.0, 0.0], "fov_y": 60.0},
            "environment": {"pixels": pixels, "rotate_y": rotate_y, **env},
            "objects": [{"shape": "sphere", "center": [0.0, 0.0, 0.0], "radius": 0.5, "material": "m"}],
            "materials": {"m": {"type": "lambert", "albedo": [0.5, 0.5, 0.5]}}}


# ----------------------------------------------------------------------------- the filter
def test_bilinear_is_the_texels_at_their_centres_and_between_them_linear():
    pixels = _map()
    h, w = pixels.shape[:2]
    r, c = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    u, v = ((c + 0.5) / w).ravel(), ((r + 0.5) / h).ravel()
    np.testing.assert_allclose(bilinear(pixels, u, v), pixels.reshape(-1, 3), rtol=1e-6)
    # halfway between two columns of one row: their mean; between two rows: theirs
    mid = bilinear(pixels, np.array([3.0 / w]), np.array([2.5 / h]))
    np.testing.assert_allclose(mid[0], (pixels[2, 2] + pixels[2, 3]) / 2, rtol=1e-6)
    mid = bilinear(pixels, np.array([2.5 / w]), np.array([3.0 / h]))
    np.testing.assert_allclose(mid[0], (pixels[2, 2] + pixels[3, 2]) / 2, rtol=1e-6)


def test_bilinear_wraps_in_u_and_is_clamped_in_v():
    pixels = _map()
    h, w = pixels.shape[:2]
    seam = bilinear(pixels, np.array([0.0, 1.0 - 1e-7]), np.array([4.5 / h, 4.5 / h]))
    np.testing.assert_allclose(seam, np.repeat(((pixels[4, 0] + pixels[4, -1]) / 2)[None], 2, 0), rtol=1e-5)
    poles = bilinear(pixels, np.array([5.5 / w, 5.5 / w]), np.array([0.0, 1.0 - 1e-7]))
    np.testing.assert_allclose(poles, pixels[[0, -1], 5], rtol=1e-6)


def test_environment_background_nearest_is_eval_and_bilinear_is_the_filter():
    rng = np.random.default_rng(3)
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    env = Environment(_map(), 1.0, 25.0)
    assert env.background == "nearest"
    np.testing.assert_array_equal(env.eval_background(d), env.eval(d))
    other = env.with_background("bilinear")
    assert other.pixels is env.pixels and env.background == "nearest"
    uv = env.world_to_square(d)
    np.testing.assert_allclose(other.eval_background(d), bilinear(env.pixels, uv[:, 0], uv[:, 1]), rtol=1e-6)
    with pytest.raises(wavlight.WavlightError, match="background must be one of nearest | bilinear"):
        Environment(_map(), background="cubic")
    hidden = env.with_background("none")
    assert hidden.pixels is env.pixels
    np.testing.assert_array_equal(hidden.eval_background(d), np.zeros((len(d), 3), np.float32))


# ----------------------------------------------------------------------------- the kernels and their twins
@pytest.mark.parametrize("background", ("nearest", "bilinear", "none"))
def test_render_kernel_equals_its_twin_and_hits_are_unchanged(device, background):
    """render_full on the device and with the numpy twin; a pixel whose samples all hit the
    sphere is the same with either background (the lighting is the map's texels)."""
    scene = wavlight.load_dict(_dict(_map()))
    kw = dict(spp=4, strategy="mis", seed=3, background=background)
    gpu = wavlight.render_full(scene, **kw)
    cpu = wavlight.render_full(scene, backend="numpy", **kw)
    assert gpu.stats["background"] == background
    np.testing.assert_allclose(gpu.image, cpu.image, rtol=1e-4, atol=1e-5)
    near = wavlight.render_full(scene, spp=4, strategy="mis", seed=3, background="nearest")
    centre = (slice(8, 12), slice(10, 14))   # inside the sphere's disc
    np.testing.assert_array_equal(gpu.image[centre], near.image[centre])
    if background == "bilinear":
        assert not np.allclose(gpu.image[0, :4], near.image[0, :4])   # the sky: filtered
    if background == "none":   # the sky's pixels miss with every sample: black
        np.testing.assert_array_equal(gpu.image[0, :4], 0.0)
        assert (near.image[0, :4] > 0).all()


@pytest.fixture(scope="module")
def small_bake(device):
    scene = wavlight.load_dict(_dict(_map(), rotate_y=0.0))
    return scene, wavlight.bake(scene, spp=4, levels=3, terms=16, priority="transfer")


def test_frame_background_bilinear_kernel_equals_its_twin(small_bake):
    scene, transfer = small_bake
    for rot in (0.0, 37.0, -90.0, 359.999):
        gpu = transfer.frame(rotate_y=rot, background="bilinear")
        cpu = transfer.frame(rotate_y=rot, background="bilinear", backend="numpy")
        np.testing.assert_allclose(gpu, cpu, rtol=1e-5, atol=1e-6)
        near = transfer.frame(rotate_y=rot)
        hit = np.zeros(transfer.width * transfer.height, bool)
        hit[np.asarray(transfer._s["background_pixel"], np.int64)] = True
        hit = ~hit.reshape(transfer.height, transfer.width)   # no sample missed: the relit product alone
        np.testing.assert_array_equal(gpu[hit], near[hit])


def test_a_frame_without_background_is_the_frame_less_its_background_part(small_bake):
    """background="none": the relit frame without the map where camera samples missed; the
    nearest frame is it plus the background part (background_reference at the same samples:
    exactly on the numpy backend), and the device frame is its twin's."""
    from wavlight.relight import frame

    scene, transfer = small_bake
    pixels = np.asarray(transfer._s["background_pixel"], np.int64)
    assert len(pixels)
    for rot in (0.0, 37.0):
        gpu = transfer.frame(rotate_y=rot, background="none")
        cpu = transfer.frame(rotate_y=rot, background="none", backend="numpy")
        np.testing.assert_allclose(gpu, cpu, rtol=1e-5, atol=1e-6)
        near = transfer.frame(rotate_y=rot, backend="numpy")
        env = transfer.environment(None, 1.0)
        u0, row = frame.background_lookup(transfer._s["background_dir"], env.height)
        part = frame.background_reference(env.pixels, rot, transfer._s["background_mask"], u0, row)
        both = cpu.copy()
        both.reshape(-1, 3)[pixels] += part
        np.testing.assert_array_equal(both, near)
        assert (part > 0).any()
        hit = np.ones(transfer.width * transfer.height, bool)
        hit[pixels] = False
        hit = hit.reshape(transfer.height, transfer.width)
        np.testing.assert_array_equal(gpu[hit], transfer.frame(rotate_y=rot)[hit])


@pytest.mark.parametrize("background", ("nearest", "bilinear", "none"))
def test_converge_kernel_equals_its_twin(small_bake, background):
    from wavlight.relight.converge import ConvergeFrames

    scene, transfer = small_bake
    gpu = ConvergeFrames(transfer, scene).frame(None, 37.0, spp=2, seed=1, background=background)
    cpu = ConvergeFrames(transfer, scene, backend="numpy").frame(None, 37.0, spp=2, seed=1, background=background)
    assert gpu.stats["background"] == background
    np.testing.assert_allclose(gpu.image, cpu.image, rtol=1e-4, atol=1e-5)


def test_an_unbiased_frame_without_background_drops_the_misses_alone(small_bake):
    """converge_shade with background="none": the same samples as with nearest; pixels whose
    bake samples all hit are the same numbers, those whose samples all miss are 0, and a
    silhouette's pixel loses at most its missing share of the brightest texel."""
    from wavlight.relight.converge import ConvergeFrames, bake_hits

    scene, transfer = small_bake
    frames = ConvergeFrames(transfer, scene)
    near = frames.frame(None, 37.0, spp=2, seed=1)
    none = frames.frame(None, 37.0, spp=2, seed=1, background="none")
    assert none.stats["background"] == "none"
    share = bake_hits(transfer) / transfer.spp
    interior = share == 1
    for axis in (0, 1):   # and their neighbours all hit too (the frame's samples are not the bake's)
        interior &= np.roll(share, 1, axis) == 1
        interior &= np.roll(share, -1, axis) == 1
    sky = share == 0
    for axis in (0, 1):
        sky &= np.roll(share, 1, axis) == 0
        sky &= np.roll(share, -1, axis) == 0
    assert interior.any() and sky.any()
    np.testing.assert_array_equal(none.image[interior], near.image[interior])
    np.testing.assert_array_equal(none.image[sky], 0.0)
    assert (near.image[sky] > 0).all()
    top = float(transfer.environment(None, 1.0).pixels.max())
    assert (none.image <= near.image + 1e-6 * top).all()


def test_frame_background_bilinear_twin_is_the_filter_at_each_missing_sample():
    """background_bilinear_reference: the mean over the S samples of the turned map's filter at
    the missing ones (bilinear at u + rotate_y / 360), zero for the others."""
    from wavlight.relight import frame

    rng = np.random.default_rng(5)
    m, samples = 30, 6
    d = rng.normal(size=(m, samples, 3))
    dirs = (d / np.linalg.norm(d, axis=-1, keepdims=True)).astype(np.float32)
    mask = rng.integers(0, 1 << samples, m).astype(np.uint64)
    pixels = _map()
    count, uv = frame.background_uv(dirs, mask)
    got = frame.background_bilinear_reference(pixels, 50.0, count, uv)
    env = Environment(pixels, 1.0, 50.0, background="bilinear")
    want = np.zeros((m, 3))
    for i in range(m):   # the definition, pixel by pixel (a test, not a hot path)
        bits = [(int(mask[i]) >> s) & 1 for s in range(samples)]
        seen = [env.eval_background(dirs[i, s:s + 1].astype(np.float64))[0] for s in range(samples) if bits[s]]
        want[i] = np.sum(seen, axis=0) / samples if seen else 0.0
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6)


# ----------------------------------------------------------------------------- the option
def test_scene_key_and_a_bad_value():
    scene = wavlight.load_dict(_dict(_map(), background="bilinear"))
    assert scene.environment.background == "bilinear"
    assert wavlight.load_dict(_dict(_map())).environment.background == "nearest"
    with pytest.raises(wavlight.WavlightError, match=r"\[environment\]\.background: must be one of nearest"):
        wavlight.load_dict(_dict(_map(), background="cubic"))


@pytest.mark.slow
def test_render_flag(tmp_path, device):
    from wavlight.cli.main import main

    scene = tmp_path / "s.toml"
    scene.write_text('[render]\nwidth = 8\nheight = 8\nspp = 1\n[camera]\neye = [0.0, 0.0, 3.0]\n'
                     'target = [0.0, 0.0, 0.0]\n[environment]\nprocedural = "sky"\n')
    out = CliRunner().invoke(main, ["render", str(scene), "-o", str(tmp_path / "a.png"), "--json", "-q",
                                    "--background", "bilinear", "--strategy", "cosine"])
    assert out.exit_code == 0, out.output
    assert json.loads(out.output.strip().splitlines()[-1])["background"] == "bilinear"
    out = CliRunner().invoke(main, ["render", str(scene), "-o", str(tmp_path / "b.png"), "--background", "cubic"])
    assert out.exit_code == 2 and "Traceback" not in out.output
    # none: nothing is hit in this scene, the PNG black
    from PIL import Image

    out = CliRunner().invoke(main, ["render", str(scene), "-o", str(tmp_path / "c.png"), "--json", "-q",
                                    "--background", "none", "--strategy", "cosine"])
    assert out.exit_code == 0, out.output
    assert json.loads(out.output.strip().splitlines()[-1])["background"] == "none"
    assert not np.asarray(Image.open(tmp_path / "c.png")).any()


def test_frame_flag_none_is_black_where_nothing_is_hit(tmp_path, small_bake):
    """wavlight frame --background none on a lighting bake: the PNG black where every bake sample
    missed, the relit object kept; an object bake refuses the flag in one line (above)."""
    from PIL import Image

    from wavlight.cli.main import main
    from wavlight.relight.converge import bake_hits

    scene, transfer = small_bake
    path = tmp_path / "l.wlt"
    wavlight.bake(scene, spp=4, levels=3, terms=16, priority="transfer", output=str(path))
    out = CliRunner().invoke(main, ["frame", str(path), "-o", str(tmp_path / "f.png"), "--background", "none",
                                    "--json", "-q"])
    assert out.exit_code == 0, out.output
    assert json.loads(out.output.strip().splitlines()[-1])["background"] == "none"
    png = np.asarray(Image.open(tmp_path / "f.png"))
    hits = bake_hits(transfer)
    assert not png[hits == 0].any() and png[hits == transfer.spp].any()


def test_the_viewer_defaults_to_bilinear_and_the_commands_to_nearest():
    from wavlight.options import BACKGROUND
    from wavlight.relight.settings import FRAME, VIEWER

    assert BACKGROUND.default == FRAME["background"].default == "nearest"
    assert VIEWER["background"].default == "bilinear"


def test_an_object_bakes_frames_refuse_the_flag():
    """An object bake's background is its static image's: --background does not apply to it; a
    lighting and a view bake's Frames take it."""
    from wavlight.relight.frames import CameraFrames, LightingFrames, ObjectFrames

    assert "background" in LightingFrames.flags and "background" in CameraFrames.flags
    with pytest.raises(wavlight.WavlightError, match="--background does not apply"):
        ObjectFrames.refuse_held("o.wlt", {"background": "bilinear"})
    LightingFrames.refuse_held("l.wlt", {"background": "bilinear"})
