"""Example data by name: the assets wavlight ships, and those it fetches on first use.

    import wavlight.data
    wavlight.data.names()                      # every asset's name
    wavlight.data.path("rooitou_park_512")     # shipped: the package's own file
    wavlight.data.path("bunny")                # fetched: downloaded once into data_dir(), then reused

A scene names an asset as ``"data:NAME"`` in ``[environment] file`` and ``[[objects]] mesh``, and
so do ``wavlight frame --env`` and ``wavlight view --env``: all go through :func:`resolve`.

The registry, ``registry.toml`` beside this file, gives each asset's file, sha256, size, licence and
origin; ``SOURCES.md`` credits each one. Shipped assets (CC0 or public domain, 1.7 MB together)
are package files under ``assets/``. The others (the 1k Poly Haven maps, the Debevec probes, the
Stanford meshes: too large to ship, or under terms that an MIT package cannot carry) are
downloaded from their origin repository at a pinned commit,
``https://raw.githubusercontent.com/<repository>/<commit>/<source>``, by pooch (with a progress
bar on a terminal), checked against their size and sha256 and kept in :func:`data_dir`:

- ``WAVLIGHT_DATA`` (:data:`DATA_ENV`): the data folder, laid out as the registry's ``file``
  (``envmaps/rooitou_park_1k.hdr``, ``meshes/bunny.ply``). A file found there with the right
  hash is used without any network; a missing one is downloaded into it. Default:
  ``platformdirs.user_cache_dir("wavlight")/data``.
- ``WAVLIGHT_DATA_URL`` (:data:`URL_ENV`): the base URL of a mirror laid out like the data
  folder, used instead of the origins (the tests serve one on 127.0.0.1).

Every failure (an unknown name, no connection, a wrong hash, a folder that cannot be written)
is one :class:`wavlight.errors.WavlightError` line that names the asset. Why this split:
docs/decisions/data-registry.md.
"""
from __future__ import annotations

import difflib
import os
import re
import sys
import tomllib
import urllib.parse
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from ..cache import cache_root
from ..errors import WavlightError, one_line, shown

#: the environment variable naming the data folder (default: the user cache, :func:`data_dir`)
DATA_ENV = "WAVLIGHT_DATA"
#: the environment variable naming a mirror's base URL, used instead of the origins
URL_ENV = "WAVLIGHT_DATA_URL"
#: how a scene names an asset: ``"data:NAME"``
PREFIX = "data:"
#: where a fetched asset comes from
ORIGIN_URL = "https://raw.githubusercontent.com/{repository}/{commit}/{source}"
#: the shipped files (``assets/<file>``) and the registry
HERE = Path(__file__).resolve().parent
ASSETS = HERE / "assets"
REGISTRY = HERE / "registry.toml"
#: what an asset is, from the first folder of its ``file``
KINDS = {"envmaps": "environment map", "meshes": "mesh"}


@dataclass(frozen=True)
class Asset:
    """One registry entry (the keys of registry.toml)."""

    name: str
    file: str              # relative path: under ASSETS when shipped, else under the data folder
    sha256: str
    bytes: int
    shipped: bool
    licence: str
    description: str
    repository: str | None = None   # origin on GitHub: owner/name, pinned commit, path there
    commit: str | None = None
    source: str | None = None
    derived_from: str | None = None  # a shipped map made from this asset by derive.py

    @property
    def kind(self) -> str:
        """``"environment map"`` or ``"mesh"``."""
        return KINDS[self.file.split("/", 1)[0]]

    @property
    def url(self) -> str | None:
        """The origin's download URL, or None for a derived asset."""
        if self.repository is None:
            return None
        return ORIGIN_URL.format(repository=self.repository, commit=self.commit, source=self.source)


@cache
def registry() -> dict:
    """Every asset by name (read once from registry.toml)."""
    with open(REGISTRY, "rb") as fh:
        doc = tomllib.load(fh)
    return {name: Asset(name=name, **entry) for name, entry in doc.items()}


def names(kind: str | None = None) -> list:
    """The assets' names, shipped first, optionally of one kind (``"environment map"``, ``"mesh"``)."""
    return [n for n, a in registry().items() if kind is None or a.kind == kind]


def asset(name: str) -> Asset:
    """The registry entry ``name``; an unknown name is one line listing the close ones."""
    found = registry().get(name) if isinstance(name, str) else None
    if found is None:
        raise WavlightError(f"{PREFIX}{name if isinstance(name, str) else shown(name)}: unknown asset "
                            f"({_close(name)})")
    return found


def _close(name, kind=None) -> str:
    """'close names: a, b' for a misspelt name, else the list of every name (of ``kind``)."""
    known = names(kind)
    close = difflib.get_close_matches(str(name), known, n=4) if isinstance(name, str) else []
    close += [n for n in known if isinstance(name, str) and name and name in n and n not in close]
    return f"close names: {', '.join(close[:4])}" if close else f"known: {', '.join(known)}"


def data_dir() -> Path:
    """The folder fetched assets are kept in: ``WAVLIGHT_DATA``, else the user cache's ``data``
    (``platformdirs.user_cache_dir("wavlight")``). It need not exist yet; a path that exists and
    is not a folder is refused."""
    value = os.environ.get(DATA_ENV, "").strip()
    if value:
        try:
            folder = Path(value).expanduser().absolute()
        except RuntimeError:   # ~user of no user, or no home
            raise WavlightError(f"{DATA_ENV}={value}: no such home folder") from None
        if folder.exists() and not folder.is_dir():
            raise WavlightError(f"{DATA_ENV}={value}: not a folder")
        return folder
    return cache_root() / "data"


def local_path(name: str) -> Path:
    """Where asset ``name`` is, or will be once fetched, without fetching it."""
    a = asset(name)
    return ASSETS / a.file if a.shipped else data_dir() / a.file


def path(name: str, *, progress=True) -> Path:
    """The file of asset ``name``: a shipped one's package file, a fetched one's file in
    :func:`data_dir` (downloaded first if it is not there; see :func:`fetch`)."""
    a = asset(name)
    return ASSETS / a.file if a.shipped else fetch(a, progress=progress)


def resolve(reference: str, base=None, kind: str | None = None, download: bool = True) -> str:
    """The file a scene value or an ``--env`` option names: ``"data:NAME"`` is asset NAME (of
    ``kind`` when given: a mesh named for a map is refused), fetched unless ``download`` is
    False (:func:`local_path`); anything else is a path, relative to ``base`` when given."""
    if not reference.startswith(PREFIX):
        return os.path.join(base, reference) if base is not None else reference
    name = reference[len(PREFIX):]
    a = registry().get(name)
    if a is None:
        raise WavlightError(f"{reference}: unknown asset ({_close(name, kind)})")
    if kind is not None and a.kind != kind:
        raise WavlightError(f"{reference}: is {_article(a.kind)} ({a.file}), not {_article(kind)}")
    return str(path(name) if download else local_path(name))


def _article(noun: str) -> str:
    return f"{'an' if noun[0] in 'aeiou' else 'a'} {noun}"


def source_url(a: Asset, base_url: str | None = None) -> str:
    """Where asset ``a`` is downloaded from: ``base_url`` (else ``WAVLIGHT_DATA_URL``) joined
    with its ``file``, else its origin (:attr:`Asset.url`)."""
    base = base_url if base_url is not None else os.environ.get(URL_ENV, "").strip()
    if base:
        try:
            parts = urllib.parse.urlsplit(base)
        except ValueError:   # a bracketed host left open: "http://[::1"
            parts = None
        if parts is None or parts.scheme not in ("http", "https") or not parts.netloc:
            raise WavlightError(f"{PREFIX}{a.name}: {URL_ENV if base_url is None else 'base_url'}={base}: "
                                "not an http:// or https:// URL")
        return base.rstrip("/") + "/" + a.file
    if a.url is None:
        raise WavlightError(f"{PREFIX}{a.name}: has no download URL (it is made by wavlight/data/derive.py)")
    return a.url


#: files whose hash matched, by path: (size, modification time) when checked
_verified: dict = {}


def file_sha256(file) -> str:
    """The sha256 of a file's bytes (hex)."""
    import pooch

    return pooch.file_hash(str(file), alg="sha256")


def fetch(a: Asset, *, folder=None, base_url: str | None = None, progress=True) -> Path:
    """Asset ``a``'s file in ``folder`` (default :func:`data_dir`): used as it is when it is
    there with the registry's sha256, else downloaded from :func:`source_url` by pooch, which
    checks the hash before the file takes its place; a body longer than the registry's size is
    refused as it arrives. ``progress``: True draws a bar on stderr where it is a terminal
    (tqdm), False none, or an object with pooch's progress-bar interface (``total``,
    ``update``, ``reset``, ``close``). Every failure is one WavlightError line naming the asset."""
    folder = data_dir() if folder is None else Path(folder).absolute()
    target = folder / a.file
    try:
        target.parent.resolve(strict=False)   # what pooch does first: a symbolic link loop raises
    except (OSError, RuntimeError):
        raise WavlightError(f"{PREFIX}{a.name}: {target.parent} is a symbolic link loop; set {DATA_ENV} to a "
                            "folder") from None
    if target.exists():
        _check(a, target)
        return target
    url = source_url(a, base_url)
    host = urllib.parse.urlsplit(url).netloc
    remedy = f"put the file in a folder and set {DATA_ENV} to it"
    bar = (_Bar(f"{PREFIX}{a.name}") if _is_terminal(sys.stderr) else None) if progress is True else progress
    import pooch
    import requests

    logger = pooch.get_logger()   # its "Downloading data from ..." line: the bar says enough
    level = logger.level
    logger.setLevel("WARNING")
    try:
        pooch.retrieve(url, known_hash=f"sha256:{a.sha256}", fname=target.name, path=str(target.parent),
                       downloader=_Download(_Cap(a, host, bar or None), deadline(a)))
    except requests.exceptions.HTTPError as e:
        status = getattr(e.response, "status_code", "?")
        raise WavlightError(f"{PREFIX}{a.name}: cannot download {a.file} from {host} (HTTP {status}); "
                            f"{remedy}") from None
    except requests.exceptions.RequestException as e:
        reason = ("timed out" if isinstance(e, requests.exceptions.Timeout)
                  else "no connection" if isinstance(e, requests.exceptions.ConnectionError)
                  else one_line(e, 80))
        raise WavlightError(f"{PREFIX}{a.name}: cannot download {a.file} from {host} ({reason}); {remedy}") from None
    except ValueError as e:   # pooch: the downloaded file's hash differs (the file is deleted)
        got = re.search(r"got ([0-9a-fA-F]{64})", str(e))
        raise WavlightError(f"{PREFIX}{a.name}: the file downloaded from {host} is not {a.file} of the registry "
                            f"(sha256 {got.group(1)[:16] + '...' if got else 'differs'}, expected "
                            f"{a.sha256[:16]}...); refused") from None
    except OSError as e:
        raise WavlightError(f"{PREFIX}{a.name}: cannot write {target} ({e.strerror or one_line(e)}); "
                            f"set {DATA_ENV} to a folder that can be written") from None
    finally:
        logger.setLevel(level)
        if progress is True and bar is not None:
            bar.close()
    _verified[str(target)] = _stamp(target)
    return target


def _stamp(target: Path):
    st = target.stat()
    return st.st_size, st.st_mtime_ns


def _check(a: Asset, target: Path) -> None:
    """A file already in the data folder: its sha256 must be the registry's (checked once per
    process while its size and time stay the same)."""
    if not target.is_file():
        raise WavlightError(f"{PREFIX}{a.name}: {target} is not a file")
    stamp = _stamp(target)
    if _verified.get(str(target)) == stamp:
        return
    try:
        got = file_sha256(target)
    except OSError as e:
        raise WavlightError(f"{PREFIX}{a.name}: cannot read {target} ({e.strerror or one_line(e)})") from None
    if got != a.sha256:
        raise WavlightError(f"{PREFIX}{a.name}: {target} is not the registry's file (sha256 {got[:16]}..., expected "
                            f"{a.sha256[:16]}...); remove it to download it again")
    _verified[str(target)] = stamp


#: bytes pooch reads at a time (its HTTPDownloader's chunk_size): it counts them per chunk
CHUNK_BYTES = 1024


#: a download's deadline: this many seconds, plus the asset's size at this many bytes a second
#: (a mirror that sends a byte at a time meets every read's timeout and never the deadline)
DOWNLOAD_SECONDS = 60.0
DOWNLOAD_RATE = 20_000
#: the seconds to connect, and to wait for any next byte
CONNECT_SECONDS, READ_SECONDS = 10.0, 30.0


def deadline(a: Asset) -> float:
    """The seconds a download of asset ``a`` may take in all."""
    return DOWNLOAD_SECONDS + a.bytes / DOWNLOAD_RATE


class _Download:
    """pooch's downloader interface (``(url, output_file, pooch)``): a streamed GET whose body is
    read a receive at a time, so that both the registry's size (``cap``) and a deadline for the
    whole download hold whatever pace the server keeps. pooch's HTTPDownloader reads whole chunks,
    each of which a trickling server can stretch without limit."""

    def __init__(self, cap, seconds: float):
        self.cap, self.seconds = cap, seconds

    def __call__(self, url, output_file, pooch_object):
        import time

        import requests
        import urllib3

        start = time.monotonic()
        with requests.get(url, stream=True, timeout=(CONNECT_SECONDS, READ_SECONDS)) as r:
            r.raise_for_status()
            self.cap.total = int(r.headers.get("content-length") or 0)
            out = open(output_file, "wb") if isinstance(output_file, (str, os.PathLike)) else output_file
            try:
                while True:
                    try:
                        chunk = r.raw.read1(1 << 16, decode_content=True)
                    except urllib3.exceptions.ReadTimeoutError as e:   # as requests' own reads say it
                        raise requests.exceptions.ReadTimeout(str(e)) from None
                    except urllib3.exceptions.HTTPError as e:
                        raise requests.exceptions.ConnectionError(str(e)) from None
                    if not chunk:
                        break
                    out.write(chunk)
                    self.cap.update(len(chunk))
                    if time.monotonic() - start > self.seconds:
                        raise WavlightError(f"{PREFIX}{self.cap.asset.name}: the download from {self.cap.host} took more "
                                            f"than {self.seconds:.0f} s ({self.cap.done} of {self.cap.asset.bytes} "
                                            f"bytes); put the file in a folder and set {DATA_ENV} to it")
            finally:
                if out is not output_file:
                    out.close()
                self.cap.close()


class _Cap:
    """pooch's progress-bar interface, passing its reports on to ``bar`` (None: no bar), that
    stops a download as soon as the server announces or sends more bytes than the registry's
    size of asset ``a`` (a mirror serving something else must not fill the disk): a one-line
    WavlightError, pooch's temporary file removed."""

    def __init__(self, a: Asset, host: str, bar):
        self.asset, self.host, self.bar, self.done = a, host, bar, 0

    def _refuse(self, size: int):
        raise WavlightError(f"{PREFIX}{self.asset.name}: the file downloaded from {self.host} is not "
                            f"{self.asset.file} of the registry (more than its {self.asset.bytes} bytes: "
                            f"{size}); refused")

    @property
    def total(self):
        return None if self.bar is None else self.bar.total

    @total.setter
    def total(self, value):   # the Content-Length, 0 where the server gives none
        if value and value > self.asset.bytes:
            self._refuse(value)
        if self.bar is not None:
            self.bar.total = value

    def update(self, n):
        self.done += n
        if self.done > self.asset.bytes + CHUNK_BYTES:   # pooch counts whole chunks
            self._refuse(self.done)
        if self.bar is not None:
            self.bar.update(n)

    def reset(self):
        self.done = 0
        if self.bar is not None:
            self.bar.reset()

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _is_terminal(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):   # no isatty, or a closed stream
        return False


def _columns(stream) -> int:
    """The width of the terminal ``stream`` writes to, 80 where it does not say."""
    try:
        return os.get_terminal_size(stream.fileno()).columns or 80
    except (AttributeError, OSError, ValueError):
        return 80


class _Bar:
    """pooch's progress-bar interface over a tqdm bar that is made only when the server answers
    (pooch sets ``total`` then): a failed connection draws nothing but its error line. Drawn
    where stderr is a terminal, never wider than it."""

    def __init__(self, label: str):
        self.label, self.bar = label, None

    @property
    def total(self):
        return None if self.bar is None else self.bar.total

    @total.setter
    def total(self, value):
        from tqdm import tqdm

        if self.bar is None:
            self.bar = tqdm(desc=self.label, total=value or None, unit="B", unit_scale=True, unit_divisor=1024,
                            leave=True, file=sys.stderr, ncols=max(1, min(79, _columns(sys.stderr) - 1)))
        else:
            self.bar.total = value

    def update(self, n):
        if self.bar is not None:
            self.bar.update(n)

    def reset(self):
        if self.bar is not None:
            self.bar.reset()

    def close(self):
        if self.bar is not None:
            self.bar.close()
