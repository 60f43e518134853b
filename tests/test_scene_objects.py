"""[[objects]] names and moving one object: Scene.find_object, without and moved give the scene
that a file with the object's keys changed (or the object left out) gives."""
from __future__ import annotations

import numpy as np
import pytest

import wavlight
from wavlight import WavlightError


def scene_dict(translate=(0.0, 0.5, 0.0), rotate=None, with_ball=True):
    ball = {"shape": "sphere", "name": "ball", "radius": 0.5, "subdivisions": 2, "translate": list(translate),
            "scale": [1.0, 0.5, 1.0]}
    if rotate is not None:
        ball["rotate"] = list(rotate)
    floor = {"shape": "quad", "size": 4.0}
    return {"environment": {"procedural": "sky"}, "objects": ([ball] if with_ball else []) + [floor]}


def test_names_and_lookup():
    scene = wavlight.load_dict(scene_dict())
    assert scene.find_object("ball").index == 0 and scene.find_object(1).index == 1
    assert scene.find_object("1").name is None
    with pytest.raises(WavlightError, match=r"no object 'cube' \(objects: 0 \(ball\), 1\)"):
        scene.find_object("cube")
    with pytest.raises(WavlightError, match="no object 5"):
        scene.find_object(5)
    d = scene_dict()
    d["objects"][1]["name"] = "ball"
    with pytest.raises(WavlightError, match=r"\[\[objects\]\]\[1\]\.name: must be a non-empty name no other"):
        wavlight.load_dict(d)


def test_moved_and_without_equal_the_edited_files():
    scene = wavlight.load_dict(scene_dict())
    ball = scene.find_object("ball")
    moved = scene.moved(ball, translate=[1.0, 0.6, -0.5], rotate=[0.0, 0.0, 1.0, 40.0])
    edited = wavlight.load_dict(scene_dict((1.0, 0.6, -0.5), (0.0, 0.0, 1.0, 40.0)))
    np.testing.assert_allclose(moved.vertices, edited.vertices, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(moved.faces, edited.faces)
    assert moved.content_hash != scene.content_hash
    assert scene.moved(ball).vertices.tobytes() == scene.vertices.tobytes()   # its own keys
    rest = scene.without(ball)
    alone = wavlight.load_dict(scene_dict(with_ball=False))
    assert len(rest.faces) == len(alone.faces) == 2
    np.testing.assert_allclose(rest.vertices[rest.faces], alone.vertices[alone.faces], atol=1e-7)
    img = wavlight.render(rest, spp=2, width=8, height=6, strategy="mis")
    np.testing.assert_array_equal(img, wavlight.render(alone, spp=2, width=8, height=6, strategy="mis"))
