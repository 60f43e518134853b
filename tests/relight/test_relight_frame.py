"""The relit frame's fast paths (wavlight.relight.frame, lighting.select_terms): each against
its definition on inputs made to hit its edge cases; the kernels against their numpy twins."""
from __future__ import annotations

import numpy as np
import pytest

from wavlight import haar
from wavlight.relight import lighting


def select_by_sort(coeffs, terms, kind, rms=None):
    """The definition: the first K of the coefficients sorted by (-priority, index)."""
    p = lighting.priority(coeffs, kind, rms)
    k = min(terms, int(np.count_nonzero(p)))
    return np.sort(np.lexsort((np.arange(p.size), -p))[:max(k, 0)]).astype(np.int64)


@pytest.mark.parametrize("kind", lighting.PRIORITIES)
def test_select_terms_equals_the_sort(kind):
    """The partition keeps the same set as a full sort, ties (many equal priorities, zeros)
    included."""
    rng = np.random.default_rng(11)
    cases = [haar.forward(rng.random((3, 16, 16))),
             haar.forward(np.round(rng.random((3, 16, 16)) * 3)),                # many equal coefficients
             np.where(rng.random((3, 16, 16)) < 0.7, 0.0, 1.0),                   # zeros and one value
             np.zeros((3, 16, 16))]
    rms = np.round(rng.random(256) * 4) / 4                                        # ties, and zeros
    for c in cases:
        for terms in (1, 5, 17, 64, 200, 256, 1000):
            got = lighting.select_terms(c, terms, kind, rms)
            np.testing.assert_array_equal(got, select_by_sort(c, terms, kind, rms))


# ----------------------------------------------------------------------------- kernels and twins
@pytest.mark.parametrize("bits", (8, 16))
def test_product_kernel_writes_the_image_its_twin_does(device, bits):
    """frame_product on an image whose sides are not whole blocks (edge blocks cut, a row of
    eight pixels cut), entries of 8 and 16 bits, coefficients missing from some blocks: the
    frame the twin untiles."""
    from wavlight import cl
    from wavlight.relight import frame

    rng = np.random.default_rng(5)
    width, height, block = 37, 21, 16
    blocks_x, n_blocks, n_coeffs = 3, 6, 64
    offsets = np.where(rng.random((n_coeffs, n_blocks)) < 0.6, 0, -1).astype(np.int32)
    n_entries = int((offsets >= 0).sum())
    offsets[offsets >= 0] = rng.permutation(n_entries)
    dtype = np.int8 if bits == 8 else np.int16
    info = np.iinfo(dtype)
    data = rng.integers(info.min, info.max, (n_entries, block * block), endpoint=True).astype(dtype)
    scale = rng.uniform(0.5, 2.0, n_entries).astype(np.float32) / info.max
    albedo = rng.uniform(0.1, 1.0, (height, width, 3)).astype(np.float32)
    entries = frame.DeviceEntries(offsets, scale, data)
    for k in (0, 1, 7, 64):
        columns = np.sort(rng.choice(n_coeffs, k, replace=False)).astype(np.int64)
        values = rng.normal(size=(k, 3))
        out = cl.empty(12 * width * height)
        entries.image(columns, values, cl.to_device(albedo), blocks_x, width, height, out)
        got = cl.read(out, (height, width, 3), np.float32, cl.thread_queue())
        want = frame.image_reference(offsets, scale, data, columns, values, albedo, blocks_x)
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6 * max(np.abs(want).max(), 1e-30))


def sample_directions(rng, m, samples):
    """(m, samples, 3) directions: per pixel a centre, its samples spread by 0 (all alike),
    1e-6, 1e-3 (a pixel), 0.01, 0.05 or 0.5 (many texels and rows); centres near the seam u = 0
    and the poles among them."""
    centre = rng.normal(size=(m, 3))
    centre[: m // 8] = [0.0, 0.1, -1.0]                          # u = 0: the seam of the map
    centre[m // 8: m // 6] = [1e-3, 1.0, 2e-3]                    # a pole
    spread = rng.choice([0.0, 1e-6, 1e-3, 0.01, 0.05, 0.5], m)
    d = centre[:, None, :] + spread[:, None, None] * rng.normal(size=(m, samples, 3))
    return (d / np.linalg.norm(d, axis=-1, keepdims=True)).astype(np.float32)


@pytest.mark.parametrize("samples", (64, 20, 1))
def test_background_kernel_equals_its_twin(device, samples):
    """frame_background (runs of one texel) against the per-sample twin: masks full, partial
    and empty, footprints from one texel to many rows, the seam, rotations of either sign, of
    whole texels and of a hair."""
    from wavlight import cl
    from wavlight.relight import frame

    rng = np.random.default_rng(7)
    m = 400
    dirs = sample_directions(rng, m, samples)
    full = np.uint64((1 << samples) - 1) if samples < 64 else np.uint64(2 ** 64 - 1)
    mask = np.where(rng.random(m) < 0.6, full,
                    rng.integers(0, 2 ** 63, m, dtype=np.uint64) & full).astype(np.uint64)
    mask[:5] = 0
    width, height = 40, 23
    pixel = rng.permutation(width * height)[:m].astype(np.uint32)
    for env_h, env_w in ((16, 32), (64, 128)):
        env = rng.uniform(0.0, 10.0, (env_h, env_w, 3)).astype(np.float32)
        bg = frame.background_samples(dirs, mask, env_h)
        u0, row = frame.background_lookup(dirs, env_h)
        assert np.array_equal(bg.count, [bin(int(x)).count("1") for x in mask])
        n0, n1 = bg.seg[:, 0, 3].view(np.uint32), bg.seg[:, 1, 3].view(np.uint32)
        if samples > 1:   # pixels in one map row, in two, in more: each of the kernel's paths
            assert ((n0 == bg.count) & (n0 > 0)).sum() > 20 and ((n1 > 0) & (n0 + n1 == bg.count)).sum() > 20
            assert (n0 + n1 < bg.count).sum() > 20
        buffers = (cl.to_device(bg.count), cl.to_device(bg.seg), cl.to_device(bg.u0), cl.to_device(bg.row),
                   cl.to_device(pixel))
        for rot in (0.0, 1e-9, -1e-9, 45.0, -90.0, 360.0 / env_w * 3, 180.0 / env_w, 359.999, -359.5):
            out = cl.to_device(np.zeros((height, width, 3), np.float32), writable=True)
            frame.background_cl(cl.to_device(env), env_w, rot, buffers, m, samples, out)
            got = cl.read(out, (height, width, 3), np.float32, cl.thread_queue()).reshape(-1, 3)[pixel.astype(np.int64)]
            want = frame.background_reference(env, rot, mask, u0, row)
            # the same texels; a run of n samples in one texel is added as n times the texel
            np.testing.assert_allclose(got, want, rtol=samples * 2.0 ** -23, atol=0)
            assert np.all(got[mask == 0] == 0)


@pytest.mark.parametrize("levels", (1, 3, 4, 5, 7))
def test_lighting_kernels_equal_their_twin_bit_for_bit(device, levels):
    """lighting_tiles and lighting_top: the Haar coefficients of the turned, scaled map's texels,
    the numpy projection's and transform's, bit for bit, for maps narrower and wider than the
    texels, any rotation (whole texels, either sign, past a turn), any scale."""
    from wavlight.envmap import Environment

    if not lighting.DeviceProjector.available():
        pytest.skip("the device has no doubles")
    rng = np.random.default_rng(levels)
    for h, w in ((8, 16), (37, 70), (64, 256)):
        env = Environment(rng.gamma(0.5, 2.0, (h, w, 3)).astype(np.float32), 1.0, 0.0, "random")
        projector = lighting.Projector(env, levels)
        device = lighting.DeviceProjector(projector)
        for rot, scale in ((0.0, 1.0), (360.0 * 3 / (1 << levels), 1.0), (-47.3, 0.25), (359.99, 3.0), (1e-9, 1.0),
                           (-1e-9, 1.0)):
            want = lighting.coefficients(projector(rot, scale))
            np.testing.assert_array_equal(device.coefficients(rot, scale), want)


# ----------------------------------------------------------------------------- frames
@pytest.fixture(scope="module")
def small_bake(tmp_path_factory, device):
    """A glossy sphere on a floor under a map with a small bright light, baked (24 x 20 pixels: edge
    blocks), and a second map of another height."""
    import wavlight
    from scenes_util import write_lamp_sky, write_raw_image

    folder = tmp_path_factory.mktemp("maps")
    rng = np.random.default_rng(3)
    write_lamp_sky(folder, rng=rng)   # a small bright light
    write_raw_image(folder / "other.exr", rng.uniform(0.1, 3.0, (24, 48, 3)).astype(np.float32))
    scene = wavlight.load_dict({
        "render": {"width": 24, "height": 20},
        "camera": {"eye": [0.0, 1.5, 3.5], "target": [0.0, 0.5, 0.0], "fov_y": 40.0},
        "environment": {"file": "sky.exr", "rotate_y": 20.0},
        "objects": [{"shape": "sphere", "center": [0.0, 0.6, 0.0], "radius": 0.6, "subdivisions": 3, "material": "ball"},
                    {"shape": "quad", "center": [0.0, 0.0, 0.0], "size": 6.0, "material": "floor"}],
        "materials": {"ball": {"type": "ggx", "albedo": [0.9, 0.8, 0.6], "roughness": 0.3},
                      "floor": {"type": "lambert", "albedo": [0.6, 0.6, 0.6]}}}, base_dir=folder)
    path = folder / "small.wlt"
    wavlight.bake(scene, output=path, spp=8, levels=4, terms=64, priority="transfer", tolerance=1e-3, seed=2)
    return path, folder / "other.exr"


def float32_tolerance(tr, env, rot, terms):
    """(H, W, 3) the float32 rounding a frame may carry against its float64 twin: the product's sum
    of K terms in float32 (at most (K + 2) u sum_k |term_k| times the albedo, u = 2^-24) plus the
    background's sum of S samples (at most (S + 2) u times its value)."""
    from wavlight.relight import frame

    s = tr._s
    coeffs = tr.lighting(env, rot)
    cols = lighting.select_terms(coeffs, terms, tr.priority, s["rms"])
    values = coeffs.reshape(3, -1)[:, cols].T * float(4 ** tr.n_levels)
    magnitude = frame.image_reference(s["offsets"], np.abs(s["entry_scale"]), np.abs(s["entry_data"].astype(np.int32)),
                                      cols, np.abs(values), s["albedo"], tr.blocks[0])
    u = 2.0 ** -24
    tol = (len(cols) + 2) * u * magnitude.astype(np.float64)
    environment = tr.environment(env)
    u0, row = frame.background_lookup(s["background_dir"], environment.height)
    seen = frame.background_reference(environment.pixels, rot, s["background_mask"], u0, row)
    tol.reshape(-1, 3)[s["background_pixel"].astype(np.int64)] += (tr.spp + 2) * u * seen
    return tol


def test_frames_keep_nothing_that_changes_them(small_bake):
    """What a Transfer keeps between frames (the map's integrals and its projector on the device,
    the background's sorted samples per map height, the device's buffers) changes no frame: a
    turntable, another map (of another height) in between and the first map again give the
    frames of a Transfer loaded afresh for each, bit for bit, and the numpy backend's (float64
    sums) within the float32 rounding of their sums."""
    import wavlight

    path, other = small_bake
    kept = wavlight.Transfer.load(path)
    turns = lighting.turntable(kept.scene_rotate_y, 7)
    for env in (None, str(other), None):
        for rot in turns:
            got = kept.frame(env, rot, terms=48)
            fresh = wavlight.Transfer.load(path)
            np.testing.assert_array_equal(got, fresh.frame(env, rot, terms=48))
            twin = fresh.frame(env, rot, terms=48, backend="numpy")
            assert np.abs(twin).max() > 0
            assert np.all(np.abs(got - twin) <= float32_tolerance(fresh, env, rot, 48))
            fresh.close()
