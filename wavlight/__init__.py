"""wavlight: direct environment lighting with Haar wavelet product importance sampling.

    import wavlight
    scene = wavlight.load_scene("scenes/default.toml")
    image = wavlight.render(scene, spp=16, strategy="mis")   # float32 (H, W, 3)
    wavlight.save_image("default.exr", image)
"""
from .errors import ArgumentError, SanitisedInputWarning, SceneError, WavlightError
from .imageio import save_image
from .integrator import RenderResult, render, render_full
from .scene import STRATEGIES, Scene, load_scene

__version__ = "0.1.0"
__all__ = ["load_scene", "render", "render_full", "save_image", "Scene", "RenderResult",
           "WavlightError", "SceneError", "ArgumentError", "SanitisedInputWarning", "STRATEGIES", "__version__"]

#: Submodules reachable as attributes (wavlight.experiment.run_experiment, ...) without importing
#: them here: experiment and stability pull in matplotlib, which costs a second at start-up.
_LAZY = ("bsdfs", "distributions", "envmap", "experiment", "haar", "metrics", "peers", "product",
         "sampler", "stability", "strategies")


def __getattr__(name):
    if name in _LAZY:
        import importlib
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'wavlight' has no attribute {name!r}")
