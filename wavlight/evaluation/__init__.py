"""Measuring the strategies: error metrics against references (:mod:`.metrics`), batch
experiments of scenes x strategies x budgets (:mod:`.experiment`, files :mod:`.spec`, outputs
:mod:`.records` and :mod:`.charts`), the stability suite of adversarial cases (:mod:`.stability`)
and Mitsuba 3 as a peer renderer (:mod:`.peers`).

    from wavlight.evaluation import run_experiment
    results = run_experiment("experiments/example.toml", "out/example")
"""
from .experiment import format_summary, run_experiment, run_suite
from .spec import load_spec

__all__ = ["run_experiment", "run_suite", "format_summary", "load_spec"]

#: submodules imported on first use as attributes (``wavlight.evaluation.stability``): the
#: stability suite and the peers pull in what an experiment does not need
_LAZY = ("charts", "metrics", "peers", "records", "stability")


def __getattr__(name):
    if name in _LAZY:
        import importlib
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'wavlight.evaluation' has no attribute {name!r}")
