"""Dask clusters: a client of a scheduler that answers within a deadline, and the results of
submitted work as they finish, each failure mode a one-line :class:`wavlight.errors.WavlightError`
naming the address (used by ``wavlight experiment --dask`` and ``wavlight bake --dask``)."""
from __future__ import annotations

import re
import socket
import struct
import threading
import time

from .errors import WavlightError, one_line, shown

#: Seconds that a scheduler address gets to answer as a Dask scheduler with at least one worker
#: (connecting, its greeting, the client's registration, a worker): past it, a one-line error
#: naming the address. A service there that is not Dask is refused as soon as it answers.
DASK_TIMEOUT = 20.0
#: A Dask scheduler's greeting (its handshake message) is about 100 bytes; a length beyond this
#: in the first 8 bytes means another protocol (an HTTP server's "HTTP/1.1" read as a length
#: asked distributed for 3 EiB).
_DASK_GREETING_MAX = 1 << 16

_DASK_ADDRESS = re.compile(r"^(tcp|tls|ucx|ws|wss)://[^/\s]+:\d+/?$")


def connect(address, timeout: float | None = None):
    """A dask.distributed client of the scheduler at ``address`` (tcp://HOST:PORT) with at least
    one worker, or a one-line WavlightError naming the address within ``timeout`` seconds: not
    installed, not an address, nothing listening, a service that is not a Dask scheduler (it
    answers something else, or nothing at all), or a scheduler without workers.

    distributed's own Client(timeout=...) bounds only the TCP connection: a service that accepts
    and never answers kept it waiting for the scheduler's greeting without end, and one that
    answers another protocol made it allocate what the first 8 bytes said (3 EiB for "HTTP/1.1").
    So the greeting is first read here, with a deadline and a size limit (:func:`_greeting`),
    and the client is then made on a thread that is given the time left."""
    if not isinstance(address, str) or not _DASK_ADDRESS.match(address):
        raise WavlightError(f"dask {shown(address)}: expected a scheduler address tcp://HOST:PORT")
    timeout = float(DASK_TIMEOUT if timeout is None else timeout)
    try:
        from distributed import Client
    except ImportError:
        raise WavlightError(f"dask {address}: dask.distributed is not installed "
                            "(pip install 'wavlight[dask]')") from None
    deadline = time.monotonic() + timeout
    if address.startswith("tcp://"):
        _greeting(address, deadline, timeout)
    box = {}

    def connect():
        try:
            box["client"] = Client(address, timeout=max(deadline - time.monotonic(), 0.1))
        except BaseException as e:   # noqa: BLE001 (handed to the caller below)
            box["error"] = e

    thread = threading.Thread(target=connect, name=f"wavlight dask connect {address}", daemon=True)
    thread.start()
    thread.join(max(deadline - time.monotonic(), 0.1))
    if thread.is_alive():
        raise WavlightError(f"dask {address}: no answer from a Dask scheduler within {timeout:g} s")
    if "error" in box:
        e = box["error"]
        if isinstance(e, MemoryError):
            raise WavlightError(f"dask {address}: the service there does not speak Dask's protocol") from None
        if not isinstance(e, Exception):   # KeyboardInterrupt, SystemExit
            raise e
        if isinstance(e, (OSError, TimeoutError)):
            raise WavlightError(f"dask {address}: cannot connect to the scheduler ({one_line(e, 160)})") from None
        # anything else came from the other end (a worker's or a nanny's address answers the
        # client's registration with a TypeError, an incompatible version with another error)
        raise WavlightError(f"dask {address}: not a usable Dask scheduler ({type(e).__name__}: "
                            f"{one_line(e, 160)})") from None
    client = box["client"]
    try:
        client.wait_for_workers(1, timeout=max(deadline - time.monotonic(), 0.1))
    except BaseException as e:
        client.close(timeout=2)
        if isinstance(e, (TimeoutError, OSError)) or type(e).__module__.startswith(("distributed", "asyncio")):
            raise WavlightError(f"dask {address}: the scheduler has no workers (waited {timeout:g} s): start "
                                "one with 'dask worker " + address + "'") from None
        raise
    return client


def finished(client, futures, address, timeout):
    """The futures as they finish. While none finishes for ``timeout`` seconds the scheduler is
    asked who it is, which it must answer within ``timeout`` seconds: a scheduler that stopped
    answering (a frozen process, a dead host whose TCP connection stays open), or one left
    without workers for two such rounds, is a one-line WavlightError instead of a wait without
    end (a run may take long; a silent scheduler may not)."""
    from distributed import wait

    pending = set(futures)
    idle = 0
    while pending:
        try:
            done, pending = wait(pending, timeout=timeout, return_when="FIRST_COMPLETED")
        except TimeoutError:
            try:
                info = client.sync(client.scheduler.identity, callback_timeout=timeout)
            except Exception:   # noqa: BLE001 (TimeoutError, a closed comm)
                raise WavlightError(f"dask {address}: the scheduler stopped answering (no reply within "
                                    f"{timeout:g} s); the runs finished before are kept: run the experiment "
                                    "again to resume") from None
            idle = 0 if (info or {}).get("workers") else idle + 1
            if idle >= 2:   # (one round for a worker that a nanny restarts)
                raise WavlightError(f"dask {address}: the scheduler has had no workers for {2 * timeout:g} s; the "
                                    "runs finished before are kept: start a worker and run the experiment again "
                                    "to resume")
            continue
        idle = 0
        yield from done


def _greeting(address, deadline, timeout):
    """Read a Dask comm's greeting (its handshake: the listener speaks first) from ``address``
    with a raw socket by ``deadline``; a one-line WavlightError when nothing listens, nothing
    comes in time, or what comes is not a Dask handshake. The connection is then closed (the
    scheduler logs nothing worse than a closed comm)."""
    host, port = address[len("tcp://"):].rstrip("/").rsplit(":", 1)
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host

    def left():
        t = deadline - time.monotonic()
        if t <= 0:
            raise socket.timeout
        return t

    try:
        with socket.create_connection((host, int(port)), timeout=left()) as sock:
            def read(n):
                buf = b""
                while len(buf) < n:
                    sock.settimeout(left())
                    chunk = sock.recv(n - len(buf))
                    if not chunk:
                        raise ConnectionResetError("the connection was closed")
                    buf += chunk
                return buf

            (size,) = struct.unpack("<Q", read(8))
            if not 0 < size <= _DASK_GREETING_MAX:
                raise WavlightError(f"dask {address}: the service there does not speak Dask's protocol (its first "
                                    "bytes are not a Dask greeting)")
            body = read(size)
    except socket.timeout:
        raise WavlightError(f"dask {address}: no answer from a Dask scheduler within {timeout:g} s "
                            "(the connection was accepted, nothing came back)") from None
    except (OSError, ValueError, OverflowError) as e:   # (OverflowError: a port beyond 65535)
        raise WavlightError(f"dask {address}: cannot connect to the scheduler "
                            f"({getattr(e, 'strerror', None) or one_line(e, 160)})") from None
    try:
        from distributed.protocol import loads
        from distributed.protocol.utils import unpack_frames
        info = loads(unpack_frames(body))
    except Exception:   # noqa: BLE001 (any garbage: msgpack, struct, ... errors)
        info = None
    if not isinstance(info, dict) or "compression" not in info or "python" not in info:
        raise WavlightError(f"dask {address}: the service there does not speak Dask's protocol (its greeting "
                            "is not a Dask handshake)")
