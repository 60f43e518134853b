"""`wavlight view`: the interactive viewer of a bake file, a thin layer over
:class:`wavlight.relight.viewer.Viewer`.

``view PATH [--env FILE ...] [--port P] [--no-browser]`` serves a page on 127.0.0.1 (no other
address) with sliders for the rotation, the exposure and the terms K, the maps to choose from
(index 0 is the baked one, then each ``--env`` in order), the frame rate and the converge
control; it prints the page's URL on one line, with the run's token
(``http://127.0.0.1:PORT/?token=...``: requests without it are refused), and opens it in the
system browser unless ``--no-browser``. The state is in the URL (``/?token=...&rotate_y=120&exposure=0.5&terms=256&env=1``).
A bake made with ``--vary object`` shows that factor's controls instead: the object's translation
and its rotation about +Y (``/?translate=0.3,0,0.2&rotate_y=45&exposure=0.5``), its frames and
converge by the moving-object estimator; ``--env`` does not apply to it, and ``--scene FILE``
gives the scene it was baked from where that is not at the path the bake recorded. A bake made
with ``--vary view`` orbits the camera instead: a drag on the picture turns it about its target,
the wheel or a slider sets its distance (``/?azimuth=30&elevation=15&distance=4.2&exposure=0.5``),
its frames by the view bake's approximate frame and converge by its unbiased one; ``--env`` does
not apply to it either, and ``--scene`` is as for an object bake.
Ctrl-C (or SIGTERM) stops it. Errors are one line and exit 2, as for the other commands.
"""
from __future__ import annotations

import click

from wavlight.relight.settings import VIEWER

from .common import fail, flags, given


@click.command()
@click.argument("bake_file", metavar="PATH", type=click.Path(dir_okay=False))
@flags(VIEWER.values())
def view(bake_file, maps, background, port, scene, no_browser):
    """Serve an interactive viewer of the bake file PATH on 127.0.0.1 and print its URL."""
    import threading
    import webbrowser

    from wavlight.errors import WavlightError

    try:
        from wavlight.relight.viewer import Viewer
    except ImportError as e:
        fail(f"wavlight view needs aiohttp ({e}): pip install 'wavlight[viewer]'")
    from wavlight.relight import Transfer
    from wavlight.relight.frames import FRAMES

    def ready(url):
        click.echo(url)
        if not no_browser:   # (a thread: a text-mode browser would hold the server's loop)
            threading.Thread(target=webbrowser.open, args=(url,), daemon=True).start()

    try:
        transfer = Transfer.load(bake_file)
        kind = FRAMES[transfer.varies]
        if maps and "env" not in kind.flags:
            fail(f"{bake_file}: this bake varies {kind.fixed}; {VIEWER['maps'].flag} does not apply")
        if background is not None and "background" not in kind.flags:
            fail(f"{bake_file}: this bake varies {kind.fixed}; {VIEWER['background'].flag} does not apply "
                 "(its background is its static image's)")
        viewer = Viewer(transfer, maps=maps, scene=scene, **given({"background": background}))
        viewer.serve(ready=ready, **given({"port": port}))
    except WavlightError as e:
        fail(e)
    except KeyboardInterrupt:   # a second Ctrl-C while stopping
        pass
