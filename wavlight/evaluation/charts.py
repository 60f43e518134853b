"""Charts of an experiment (matplotlib without pyplot): relMSE against spp and time, error maps."""
from __future__ import annotations

import os

import numpy as np

from . import metrics
from ..atomic import atomic_write
from ..errors import WavlightError
from .records import read_image
from .spec import Spec


#: the extra that installs the charts' matplotlib (pyproject.toml)
EXTRA = "experiments"


def require_matplotlib() -> None:
    """Before an experiment's work: a one-line WavlightError naming the extra when matplotlib,
    which only the charts use, is not installed (docs/decisions/optional-matplotlib.md)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise WavlightError(f"the experiment's charts need matplotlib, which wavlight's {EXTRA!r} extra "
                            f"installs: pip install 'wavlight[{EXTRA}]'") from None


def strategy_colours(spec):
    from matplotlib import colormaps
    cmap = colormaps["tab10"]
    return {st.label: cmap(i % 10) for i, st in enumerate(spec.strategies)}


def save_figure(fig, out_dir, stem):
    folder = os.path.join(out_dir, "charts")
    os.makedirs(folder, exist_ok=True)
    names = []
    for ext in ("png", "svg"):
        path = os.path.join(folder, f"{stem}.{ext}")
        with atomic_write(path) as tmp:
            fig.savefig(tmp, format=ext, dpi=120, metadata={"Date": None} if ext == "svg" else None)
        names.append(os.path.relpath(path, out_dir))
    return names


def error_charts(spec: Spec, groups, out_dir) -> list:
    from matplotlib.figure import Figure

    colours = strategy_colours(spec)
    files = []
    for s in spec.scenes:
        mine = [g for g in groups if g["scene"] == s.name]
        positive = [v for g in mine for v in (g["relmse_min"], g["relmse"]) if v is not None and v > 0]
        floor = min(positive) / 10 if positive else None
        for axis, xkey, xlabel in (("spp", "spp", "samples per pixel"),
                                   ("time", "total_seconds", "total seconds per render (setup + sampling)")):
            fig = Figure(figsize=(6.4, 4.4), layout="constrained")
            ax = fig.add_subplot()
            for st in spec.strategies:
                # joined in spp order on both charts: a noisy time must not zig-zag the line
                pts = sorted((g for g in mine if g["strategy"] == st.label), key=lambda g: (g["spp"], g[xkey]))
                x = np.array([g[xkey] for g in pts], float)
                y = np.array([g["relmse"] for g in pts], float)
                lo = np.array([g["relmse_min"] for g in pts], float)
                hi = np.array([g["relmse_max"] for g in pts], float)
                c = colours[st.label]
                ax.plot(x, np.where(y > 0, y, np.nan), "o-", color=c, label=st.label, lw=1.5, ms=4)
                if floor is not None and len(pts) and spec.repetitions > 1:
                    ax.fill_between(x, np.maximum(lo, floor), np.maximum(hi, floor), color=c, alpha=0.18, lw=0)
            if floor is not None:
                ax.set_xscale("log")
                ax.set_yscale("log")
            ax.set_xlabel(xlabel)
            ax.set_ylabel("relMSE")
            ax.grid(True, which="both", alpha=0.3)
            band = f"band: min-max of {spec.repetitions} repetitions" if spec.repetitions > 1 else "1 repetition"
            ax.set_title(f"{s.name}: relMSE vs {'spp' if axis == 'spp' else 'time'} (line: mean; {band})",
                         fontsize=9)
            ax.legend(fontsize=8)
            files += save_figure(fig, out_dir, f"{s.name}-{axis}")
    return files


def error_maps(spec: Spec, groups, runs, references, equal_time, out_dir) -> list:
    from matplotlib.figure import Figure

    from ..imageio import srgb_encode

    rows, cols = len(spec.scenes), 1 + len(spec.strategies)
    w0, h0 = max((references[s.name][0].shape[1], references[s.name][0].shape[0]) for s in spec.scenes)
    cell = 2.4
    fig = Figure(figsize=(cols * cell + 1.0, rows * (cell * h0 / w0 + 0.5) + 0.4), layout="constrained")
    axes = np.asarray(fig.subplots(rows, cols, squeeze=False))
    im = None
    for i, s in enumerate(spec.scenes):
        ref = references[s.name][0]
        ax = axes[i, 0]
        ax.imshow(srgb_encode(ref), interpolation="nearest")
        ax.set_title(f"{s.name}\nreference", fontsize=8)
        for j, st in enumerate(spec.strategies):
            ax = axes[i, j + 1]
            bkey = equal_time[s.name][st.label]
            g = next(g for g in groups if g["scene"] == s.name and g["strategy"] == st.label and g["budget"] == bkey)
            run = next(r for r in runs if r["scene"] == s.name and r["strategy"] == st.label
                       and r["budget"] == bkey and r["seed"] == 0)
            img = read_image(os.path.join(out_dir, run["image"]))
            im = ax.imshow(metrics.error_map(img, ref), cmap="inferno", vmin=0.0, vmax=1.0, interpolation="nearest")
            ax.set_title(f"{st.label}: {g['spp']} spp, {run['total_seconds']:.2f} s\nrelMSE {run['relmse']:.3g}",
                         fontsize=8)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    if im is not None:
        bar = fig.colorbar(im, ax=axes[:, 1:].ravel().tolist(), extend="max", shrink=0.9)
        bar.set_label("relative error √(mean (x−r)² / (r²+0.01))", fontsize=8)
    fig.suptitle(f"{spec.name}: error maps at equal time (seed 0)", fontsize=10)
    return save_figure(fig, out_dir, "error-maps")
