"""wavlight: direct environment lighting with Haar wavelet product importance sampling.

    import wavlight
    scene = wavlight.load_scene("scenes/default.toml")     # or wavlight.load_dict({...})
    image = wavlight.render(scene, spp=16)            # float32 (H, W, 3)
    wavlight.save_image("default.exr", image)

Core modules (scene, envmap, bsdfs, warp, camera, raytrace, integrator, shading, ...) are flat;
the families are packages: :mod:`wavlight.strategies` (direction sampling),
:mod:`wavlight.haar` (transform, sparse sets, products, pyramids, sampling trees) and
:mod:`wavlight.evaluation` (metrics, experiments, the stability suite, peer renderers) and
:mod:`wavlight.relight` (dynamic lighting from precomputed transfer: bake, frames, viewer);
:mod:`wavlight.data` names the example data (``data:NAME`` in scenes) and :mod:`wavlight.demos`
the example scenes that ship with wavlight.
"""
from .errors import ArgumentError, SanitisedInputWarning, SceneError, WavlightError
from .imageio import save_image
from .integrator import RenderResult, render, render_full
from .scene import Scene, load_asset, load_dict, load_scene
from .strategies import STRATEGIES
from .relight.bakes import bake
from .relight.transfer import Transfer
from .version import __version__

__all__ = ["load_scene", "load_dict", "load_asset", "render", "bake", "Transfer", "render_full", "save_image",
           "Scene", "RenderResult", "WavlightError", "SceneError", "ArgumentError", "SanitisedInputWarning",
           "STRATEGIES", "__version__"]

#: Subpackages and modules reachable as attributes (wavlight.evaluation.run_experiment, ...) without
#: importing them here: the evaluation package pulls in matplotlib, which costs a second at start-up.
_LAZY = ("bsdfs", "data", "demos", "envmap", "evaluation", "haar", "sampler", "strategies", "warp")


def __getattr__(name):
    if name in _LAZY:
        import importlib
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'wavlight' has no attribute {name!r}")
