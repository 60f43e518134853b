"""plastic (Mitsuba 3's roughplastic) in the view bake (wavlight.relight.view_frames): the walk's
two lobes against wavlight.bsdfs and the kernel against its twin, point and pixel mode, the
assembly's coat, the unbiased frame against ``mis`` at the bake's camera and at another eye,
and the approximate frames within their measured approximation error."""
from __future__ import annotations

import numpy as np
import pytest
from scenes_util import check_estimates, toml_text, write_lamp_sky

import wavlight
from wavlight import bsdfs, haar
from wavlight.relight import lighting, view_converge, view_frames, view_walk

EYE, TARGET = [2.0, 2.0, 3.0], [0.0, 0.5, 0.0]
SIZE = 24


def scene_dict(camera=None):
    """A plastic sphere on a plastic floor (another roughness, ior and colour) under a sky."""
    return {"render": {"width": SIZE, "height": SIZE},
            "camera": camera or {"eye": [0.0, 1.5, 3.5], "target": [0.0, 0.5, 0.0], "fov_y": 40.0},
            "environment": {"file": "sky.exr", "rotate_y": 20.0},
            "objects": [{"shape": "sphere", "center": [0.0, 0.6, 0.0], "radius": 0.6, "subdivisions": 3,
                         "material": "ball"},
                        {"shape": "quad", "center": [0.0, 0.0, 0.0], "size": 6.0, "material": "floor"}],
            "materials": {"ball": {"type": "plastic", "albedo": [0.7, 0.25, 0.1], "alpha": 0.2},
                          "floor": {"type": "plastic", "albedo": [0.3, 0.4, 0.5], "alpha": 0.5, "ior": 1.7}}}


@pytest.fixture(scope="module")
def baked(tmp_path_factory, device):
    """The scene's view bake (16 x 16 texels, 16 bits, nearly lossless) under a sky with a
    small bright light."""
    folder = tmp_path_factory.mktemp("relight_view_plastic")
    write_lamp_sky(folder)   # a small bright light
    (folder / "scene.toml").write_text(toml_text(scene_dict()))
    scene = wavlight.load_scene(folder / "scene.toml")
    tr = wavlight.bake(scene, folder / "plastic.wlt", vary="view", levels=4, density=400, tolerance=1e-3, bits=16)
    return folder, scene, tr


def unit_pairs(n, seed=0):
    rng = np.random.default_rng(seed)
    wi, wo = rng.normal(size=(2, n, 3))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]) + 1e-3, np.abs(wo[:, 2]) + 1e-3
    return wi / np.linalg.norm(wi, axis=1, keepdims=True), wo / np.linalg.norm(wo, axis=1, keepdims=True)


def test_the_two_lobes_are_plastics_f_cos():
    """The walk's BRDF factors of plastic's lobes, times cos_i, are bsdfs.plastic_parts (the coat,
    the part the albedo multiplies), whose sum is plastic's f cos."""
    wi, wo = unit_pairs(4000)
    for alpha, ior, albedo in ((0.05, 1.5, [0.6, 0.3, 0.1]), (0.5, 1.7, [0.2, 0.9, 0.4])):
        table = np.repeat(bsdfs.plastic_table(alpha, ior, albedo)[None], len(wi), 0)
        coat = view_walk.brdf_reference(np.full(len(wi), view_walk.VIEW_COAT), np.full(len(wi), table[0, 3]), wi, wo,
                                        table)
        base = view_walk.brdf_reference(np.full(len(wi), view_walk.VIEW_BASE), np.zeros(len(wi)), wi, wo, table)
        spec, diff = bsdfs.plastic_parts(wi, wo, table)
        assert spec.max() > 0 and diff.max() > 0
        np.testing.assert_allclose(coat * wi[:, 2], spec, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(base * wi[:, 2], diff, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose((coat + base) * wi[:, 2], bsdfs.plastic_eval(wi, wo, table), rtol=1e-9, atol=1e-12)


def test_lobes_split_plastic_items(baked):
    """Each plastic item walks its base in place and its coat appended, with its table row."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    mat = np.array([0, 1, 1, 0])
    kind, param, coat, rows = frames.lobes(mat)
    assert list(kind) == [view_walk.VIEW_BASE] * 4 + [view_walk.VIEW_COAT] * 4
    assert list(coat) == [0, 1, 2, 3]
    np.testing.assert_array_equal(rows, np.concatenate([mat, mat]) * bsdfs.PLASTIC_STRIDE)
    np.testing.assert_allclose(param[4:], frames.plastic_table[mat, 3])


def test_product_kernel_equals_its_twin(baked):
    """view_product on plastic's lobes against product_reference (points seen from two eyes),
    and the point and pixel frames (view_assemble with the coat) against the numpy frames."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    points = np.arange(0, len(frames.position), 3)
    for eye, refine in ((EYE, 0.25), ([-1.0, 0.8, 2.0], 0.1)):
        a, na, ca, ra = frames.products(points, eye, refine)
        b, nb, cb, rb = frames.products(points, eye, refine, backend="numpy")
        assert len(ca) == len(points) and (ca == cb).all() and (ra == rb).all() and a.shape == (2 * len(points), 3)
        assert np.abs(b[len(points):]).max() > 0 and np.abs(b[:len(points)]).max() > 0
        close = np.isclose(a, b, rtol=1e-4, atol=1e-6 * np.abs(b).max()).all(1)
        assert close.mean() > 0.995 and (na == nb).mean() > 0.99   # but a threshold within rounding
        np.testing.assert_allclose(a, b, rtol=2e-2, atol=1e-4 * np.abs(b).max())
    for mode in view_frames.MODES:
        fa, _ = frames.frame(EYE, TARGET, mode=mode, supersample=1)
        fb, _ = frames.frame(EYE, TARGET, mode=mode, supersample=1, backend="numpy")
        assert fb.max() > 0
        np.testing.assert_allclose(fa, fb, rtol=2e-2, atol=1e-4 * fb.max())


def test_the_coat_is_not_tinted(baked):
    """A point's value for albedo a is a B + C: with the albedo black a frame shows the coat
    alone, grey under a grey sky's light (the ball's highlight is the light's colour)."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    full, _ = frames.frame(EYE, TARGET, mode="point")
    frames.albedo_of = np.zeros_like(frames.albedo_of)
    coat, _ = frames.frame(EYE, TARGET, mode="point", backend="numpy")
    hit = full.max(-1) > 0
    assert coat[hit].sum() > 0.02 * full[hit].sum() and (coat[hit] <= full[hit] * 1.02 + 1e-6).all()


def mis_of(folder, camera):
    moved = wavlight.load_dict(scene_dict(camera), base_dir=folder)
    return wavlight.render_full(moved, spp=512, strategy="mis", seed=11)


@pytest.mark.slow
@pytest.mark.parametrize("eye, target", [(None, None), (EYE, TARGET)])
def test_unbiased_frame_equals_mis(baked, eye, target):
    """The unbiased frame (trees of base + coat / lum(albedo), converge_shade's plastic) agrees
    with mis at the bake's camera and from another eye, within the standard error; the
    approximate frames within their approximation error (APPROXIMATE_ERROR)."""
    folder, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    spp = 64
    cam = scene.camera
    camera = None if eye is None else {"eye": eye, "target": target, "fov_y": 40.0}
    r = frames.converge(eye, target, spp=spp, seed=3)
    ref = mis_of(folder, camera)
    se = np.sqrt(r.stderr.astype(np.float64) ** 2 + ref.stderr.astype(np.float64) ** 2)
    check_estimates(r.image, se, ref.image, np.ones((SIZE, SIZE), bool), spp, per_pixel=False,
                    label=f"plastic view converge vs mis from {cam.eye if eye is None else eye}")
    diff = (r.image.astype(np.float64) - ref.image).reshape(6, 4, 6, 4, 3).sum(axis=(1, 3))
    z = diff / np.sqrt((se ** 2).reshape(6, 4, 6, 4, 3).sum(axis=(1, 3)))
    assert np.abs(z).max() < 4.0, z
    for mode in view_frames.MODES:
        image, _ = frames.frame(eye, target, mode=mode)
        assert np.linalg.norm(image - ref.image) / np.linalg.norm(ref.image) < APPROXIMATE_ERROR, mode


#: the approximate frames' relative L2 error against mis on this scene, at most: measured 0.075
#: (both modes) at the bake's camera and 0.067 from EYE, mis's own noise 0.016-0.017 (the ggx ball
#: of test_relight_view.py: 0.068 and 0.060), which that test bounds at 0.12 too
#: (docs/decisions/plastic-in-the-view-bake.md)
APPROXIMATE_ERROR = 0.12


def test_walks_to_the_texels_are_the_dense_sums(baked):
    """With refine -> 0 both walks reach the texels: the base's and the coat's B equal their
    dense sums over the stored texels, sum_t T1_t f_r(w_t) (f_r the lobe's factor); the default
    walks are close to them (measured: 0.6% for the base, 1.2% for the coat)."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    points = np.arange(3, len(frames.position), 97)
    side = 1 << tr.n_levels
    coeffs = view_converge.point_coefficients(tr, points, np.arange(side * side))
    T = haar.inverse(coeffs.reshape(len(points), 3, side, side)).reshape(len(points), 3, -1)   # (I, 3, N^2) texels
    wo = np.asarray(EYE) - frames.position[points]
    wo = view_walk.lifted_view(frames.normal[points], wo / np.linalg.norm(wo, axis=1, keepdims=True))
    mat = frames.material[points]
    dirs = lighting.texel_directions(tr.n_levels).reshape(-1, 3)
    n = frames.normal[points]
    s_ax, t_ax = wavlight.warp.frame(n)
    wl = np.stack([dirs @ a.T for a in (s_ax, t_ax, n)], -1).transpose(1, 0, 2).reshape(-1, 3)   # (I N^2, 3)
    wol = np.repeat(np.stack([np.einsum("ij,ij->i", wo, a) for a in (s_ax, t_ax, n)], 1), side * side, axis=0)
    table = np.repeat(frames.plastic_table[mat], side * side, axis=0)
    I = len(points)
    got, nodes, coat, rows = frames.products(points, EYE, refine=1e-4)
    approx, few, *_ = frames.products(points, EYE)
    assert (coat == np.arange(I)).all() and nodes.max() > side * side / 2   # the texels were reached
    for kind, at in ((view_walk.VIEW_BASE, np.arange(I)), (view_walk.VIEW_COAT, rows)):
        f = view_walk.brdf_reference(np.full(len(wl), kind), np.repeat(frames.plastic_table[mat, 3], side * side),
                                     wl, wol, table).reshape(I, -1)
        dense = np.einsum("icn,in->ic", T, f)
        assert np.abs(dense).max() > 0
        np.testing.assert_allclose(got[at], dense, rtol=2e-3, atol=1e-5 * np.abs(dense).max())
        err = np.linalg.norm(approx[at] - dense) / np.linalg.norm(dense)
        assert err < 0.03, (kind, err)
