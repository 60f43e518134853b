"""An object bake of a textured scene (wavlight.relight.moving): a GLB's floor with a base-colour
texture of stripes and a gold sphere, and a moving pyramid whose one material is textured. The
bake's albedo carries the texels, its frames (the viewer's and the converged, at the bake's own
place and moved) agree with mis of the moved scene, and the kernels that read the textures agree
with their numpy twins."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

import wavlight
from assets_util import write_glb, write_textured_pyramid
from scenes_util import toml_text, write_sun_sky
from wavlight.cli.main import main
from wavlight.relight.frames import frames_for
from wavlight.relight.moving import MovingObject

OWN = (0.6, 0.0, 0.5)


def scene_dict(translate=OWN, rotate=None):
    tile = {"mesh": "p.obj", "name": "tile", "scale": 0.7, "translate": list(translate)}
    if rotate is not None:
        tile["rotate"] = list(rotate)
    return {"render": {"width": 32, "height": 24},
            "camera": {"eye": [0.0, 2.0, 4.0], "target": [0.0, 0.3, 0.0], "fov_y": 40.0},
            "environment": {"file": "sky.exr", "rotate_y": 15.0},
            "objects": [{"mesh": "a.glb"}, tile]}


@pytest.fixture(scope="module")
def textured(tmp_path_factory, device):
    folder = tmp_path_factory.mktemp("moving_textured")
    write_sun_sky(folder)                                  # a small sun: hard shadows
    write_glb(folder / "a.glb")                            # the striped floor, the gold sphere
    write_textured_pyramid(folder)                         # the moving object, textured
    (folder / "scene.toml").write_text(toml_text(scene_dict()))
    scene = wavlight.load_scene(folder / "scene.toml")
    assert scene.textured and scene.without(scene.find_object("tile")).textured
    tr = wavlight.bake(scene, folder / "tile.wlt", spp=4, levels=5, terms=256, priority="area", vary="object",
                       object="tile", static_spp=1024)
    return folder, scene, tr


def _reference(folder, translate, rotate=None, seed=9, spp=4096):
    return wavlight.render_full(wavlight.load_dict(scene_dict(translate, rotate), base_dir=folder), spp=spp,
                                strategy="mis", seed=seed)


def test_the_bake_refuses_nothing_and_its_albedo_carries_the_stripes(textured, tmp_path):
    """A textured scene bakes with --vary object (no refusal), and the pixels' albedo on the
    floor takes both stripes' colours (red: green is a small share of red; white: about equal;
    most pixels mix the two), where the floor's material alone is white."""
    folder, scene, tr = textured
    albedo = np.asarray(tr._s["albedo"], np.float64).reshape(-1, 3)
    hit = albedo.max(1) > 0
    ratio = albedo[hit, 1] / albedo[hit, 0]
    assert (ratio < 0.3).sum() > 10 and (ratio > 0.9).sum() > 3, np.percentile(ratio, [5, 50, 95])
    r = CliRunner().invoke(main, ["bake", str(folder / "scene.toml"), "-o", str(tmp_path / "t.wlt"), "--spp", "2",
                                  "--levels", "4", "--terms", "64", "--priority", "area", "--vary", "object",
                                  "--object", "tile", "--static-spp", "8", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["file_bytes"] > 0 and wavlight.Transfer.load(tmp_path / "t.wlt").varies == "object"


@pytest.mark.slow
@pytest.mark.parametrize("translate, rotate", [(OWN, None), ((1.0, 0.0, 0.2), [0.0, 1.0, 0.0, 35.0])])
def test_frames_agree_with_mis_of_the_moved_textured_scene(textured, translate, rotate):
    """The viewer's frame (OBJECT_FRAME_SPP samples: unbiased, as every frame of an object bake)
    and a converged one, at the bake's own place and moved, against mis of the moved scene: over
    the image, over the pixels that may see the (textured) object, and over those in its shadow
    on the striped floor (where the static image minus the occlusion D is nearly all of it, D
    with the floor's texel as its albedo)."""
    folder, scene, tr = textured
    frames = frames_for(tr, scene)
    state = frames.state_from({"translate": list(translate), "rotate": rotate})
    ref = _reference(folder, translate, rotate)
    mover = frames.mover
    full = mover._object_pixels(*mover.placement(translate, rotate), 32, 24)
    # the shadow from another render than the one compared with (chosen from the compared one,
    # the pixels where its noise fell low would be chosen more often)
    other = _reference(folder, translate, rotate, seed=19)
    shadow = ~full & (mover.static.mean(2) - other.image.mean(2) > 4 * other.stderr.mean(2) + 1e-3)
    assert full.sum() > 20 and shadow.sum() > 5, (full.sum(), shadow.sum())
    image, stats = frames.frame(state)
    converged = frames.converge(state, spp=64, seed=5)
    for name, (img, err) in (("frame", (image, stats["stderr"])), ("converged", (converged.image, converged.stderr))):
        diff = img.astype(np.float64) - ref.image
        var = err.astype(np.float64) ** 2 + ref.stderr.astype(np.float64) ** 2
        for part, mask in (("all", np.ones_like(full)), ("full", full), ("others", ~full), ("shadow", shadow)):
            z = diff[mask].sum(0) / np.sqrt(var[mask].sum(0))   # per channel: the stripes are red and white
            assert np.abs(z).max() < 3.5, (name, part, z)


@pytest.mark.parametrize("plastic", [False, True])
def test_the_occlusion_kernel_matches_its_numpy_twin_with_textures(textured, plastic):
    """moving_occlusion with -DTEXTURES=1 against occlusion_records_reference: the contributions
    carry the albedo of the floor's texel at each hit (Scene.albedo_at in the twin); the floor as
    it is (ggx) and made plastic (the textured albedo tints its diffuse base only)."""
    import dataclasses

    from wavlight import bsdfs
    from wavlight.relight import moving as mv

    _, scene, tr = textured
    mover = MovingObject(tr, scene)
    assert mover._kernels.textured
    rest, kernels = mover.rest, mover._kernels
    if plastic:
        rest = dataclasses.replace(rest, materials=[dataclasses.replace(m, kind=bsdfs.PLASTIC, param=0.2)
                                                    if m.name == "a.glb:floor" else m for m in rest.materials])
        kernels = mv._MovingKernels(rest, mover.rest_tracer, mover.object_tracer, mover.inside, mover._shader,
                                    mover.m, 4, True, mover._object_face_uv)
    spp, seed, tile, first = 4, 7, 321, 96
    cam = mover._camera(0, 0, tr.width * tr.height, spp, seed)
    slots = np.flatnonzero(cam.prim >= 0)
    trees, offset = mover._product_trees(0, tr.width * tr.height)
    place, box = mover._place(*mover.placement([0.2, 0.0, 0.6], [0.0, 1.0, 0.0, 30.0]))
    uv = (cam.uv[0][slots], cam.uv[1][slots])
    got = kernels.occlusion(scene.camera.eye, cam.d[slots], cam.prim[slots], cam.t[slots], slots, trees, offset, spp,
                            seed, tile, first, place, box, uv=uv)
    want = mv.occlusion_records_reference(rest, mover.rest_tracer, mover.environment, mover.inside, trees,
                                          cam.d[slots], cam.prim[slots], cam.t[slots], slots, spp, 4, seed, tile,
                                          first, place, box, offset, uv=uv)
    assert len(want.sample) > 200 and abs(len(got.sample) - len(want.sample)) <= 0.01 * len(want.sample)
    common, ig, iw = np.intersect1d(got.sample * 4 + got.j, want.sample * 4 + want.j, return_indices=True)
    assert len(common) > 0.98 * len(want.sample)
    same_dir = np.abs(got.direction[ig] - want.direction[iw]).max(1) < 1e-3
    close = np.abs(got.value[ig] - want.value[iw]).max(1) <= 2e-3 * np.abs(want.value[iw]).max(1) + 1e-6
    assert same_dir.mean() > 0.995 and (same_dir & close).mean() > 0.99, (same_dir.mean(), close.mean())
    # the texels show: the records' colours are the stripes' (green a small share of red) and white's
    v = want.value[iw][same_dir]
    ratio = v[:, 1] / np.maximum(v[:, 0], 1e-30)
    assert (ratio < (0.6 if plastic else 0.3)).mean() > 0.1 and (ratio > 0.7).mean() > 0.1, \
        np.percentile(ratio, [5, 50, 95])


def test_the_points_kernel_matches_its_numpy_twin_with_textures(textured):
    """moving_points with -DTEXTURES=1 against shading_points_reference: the texture's value at the
    hit (planes 16..18), the rest's floor and the moved object's own faces, besides the points."""
    from wavlight.relight import moving as mv

    _, scene, tr = textured
    mover = MovingObject(tr, scene)
    R, T = mover.placement([0.2, 0.0, 0.6], [0.0, 1.0, 0.0, 30.0])
    spp, seed, tile, first = 8, 11, 77, 16
    cam = mover._camera(0, 0, tr.width * tr.height, spp, seed)
    slots = np.flatnonzero(np.repeat(mover._object_pixels(R, T, tr.width, tr.height).reshape(-1), spp))
    d, prim, t, uv = cam.d[slots], cam.prim[slots], cam.t[slots], (cam.uv[0][slots], cam.uv[1][slots])
    prim_o, t_o, uv_o = mover._trace_object(R, T, scene.camera.eye.astype(np.float32), d, closest=True)
    place, _ = mover._place(R, T)
    got, got_mat = mover._kernels.points(scene.camera.eye, d, prim, t, prim_o, t_o, slots, place, mover.object.material,
                                         1e-6, spp, seed, tile, first, uv=uv, uv_object=uv_o)
    want, want_mat = mv.shading_points_reference(mover.rest, mover.rest_tracer, mover.object_tracer,
                                                 mover.object.material, mover.environment, d, prim, t, prim_o, t_o, R,
                                                 T, 1e-6, slots, spp, seed, tile, first, uv=uv, uv_object=uv_o,
                                                 object_face_uv=mover._object_face_uv)
    on_object = (prim_o >= 0) & ((prim < 0) | (t_o < t))
    np.testing.assert_array_equal(got_mat, want_mat)
    hit = want_mat >= 0
    np.testing.assert_allclose(got[0:16, hit], want[0:16, hit], rtol=1e-5, atol=2e-5)
    np.testing.assert_allclose(got[16:19], want[16:19], rtol=1e-5, atol=1e-6)     # the textures' values
    floor = hit & ~on_object & (scene.material_texture[np.maximum(want_mat, 0)] >= 0)
    for where in (on_object, floor):   # both stripes seen on the object and on the floor
        ratio = want[17, where] / want[16, where]
        assert where.sum() > 30 and (ratio < 0.3).any() and (ratio > 0.9).any(), (where.sum(), ratio)
    assert np.all(want[16:19, ~hit] == 1.0)


def test_the_kernel_frame_matches_the_numpy_frame_with_textures(textured):
    """The same frame (same random numbers) with the kernels and with their numpy twins, the
    textures read by both (the points shaded in full with their texture as the shade kernel's
    tint; NumpyShader multiplies it into the albedo)."""
    _, scene, tr = textured
    translate, rotate = (0.2, 0.0, 0.6), [0.0, 1.0, 0.0, 30.0]
    a = MovingObject(tr, scene).frame(translate, rotate, spp=8, seed=5)
    b = MovingObject(tr, scene, backend="numpy").frame(translate, rotate, spp=8, seed=5)
    assert a.stats["object_pixels"] == b.stats["object_pixels"] > 0
    diff = np.abs(a.image - b.image).max(2)
    assert (diff > 1e-3 * (1 + np.abs(b.image).max(2))).mean() < 0.03, diff.max()
    var = (b.stderr ** 2).sum()
    assert abs((a.image - b.image).sum()) < 0.5 * np.sqrt(var)
