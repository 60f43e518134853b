"""The viewer's connections: its listening socket on 127.0.0.1, the accept loop, the time a
connection may stay idle, and its log lines (one line each, rate-limited).

    listener = Listener(runner.server)           # any asyncio protocol factory (aiohttp's Server)
    port = await listener.start("127.0.0.1", 0)
    ...
    await listener.close()

Accepting. The loop is the viewer's own, not asyncio's server: at the file descriptor limit
(``accept`` fails with EMFILE or ENFILE) asyncio's server (Python 3.11) logs the failure and
goes on: a hundred attempts at a time, each scheduling another hundred a second later,
thousands of lines a second while the descriptors stay in use, the connections queued
unanswered. Here a spare descriptor (a
handle on /dev/null, held while all is well) is given up to accept the waiting connection,
answer it ``503`` (:data:`REFUSAL`) and close it, and taken again: each new connection is
refused at once, the pages already open keep their sockets and frames, and one log line per
:data:`LOG_INTERVAL_SECONDS` says so (with the count of refusals since the last). Where the
spare cannot be taken again, the loop waits :data:`ACCEPT_RETRY_SECONDS` between attempts. As
soon as an accept succeeds, connections are served again (one line says after how many
refusals).

Idle connections. A connection that is not handling a request (nor upgraded to a websocket)
is cut :data:`HTTP_IDLE_SECONDS` after it opened or after its last request ended: one that
sends nothing, a request line or headers that never end (slowloris), a keep-alive connection
left open, a half-open one whose peer vanished. The application tells the listener when a
request starts and ends (:meth:`Listener.request_started`, :meth:`Listener.request_ended`,
an aiohttp middleware) and when a connection became a websocket (:meth:`Listener.upgraded`),
whose own rules (a heartbeat every :data:`WS_HEARTBEAT_SECONDS`, closed after
:data:`WS_IDLE_SECONDS` without a message from its page) the viewer applies; a websocket whose
closing has not finished :data:`WS_CLOSE_SECONDS` after it began (a peer that reads nothing) is
cut (:meth:`Listener.cut_later`).

Log lines. :class:`OneLineLog` writes a record as one line on stderr, an exception's type and
message appended, never a traceback; a kind of line (the logger and the message's template)
is written at most once per :data:`LOG_INTERVAL_SECONDS`, the next one telling how many were
held back: a flood of bad requests or refused connections is a line every few seconds.
"""
from __future__ import annotations

import asyncio
import errno
import logging
import os
import socket
import sys
import time

from ..errors import described

#: a connection not handling a request (nor a websocket) is cut this long after it opened or its
#: last request ended: a connection that sends nothing, a request or headers that never end
#: (slowloris), an idle keep-alive connection, a half-open one
HTTP_IDLE_SECONDS = 15.0
#: a websocket without a message for this long is pinged, and closed when no pong comes back
#: within half of it (a page that vanished, a half-open connection)
WS_HEARTBEAT_SECONDS = 20.0
#: a websocket whose page sent no message (a state, an acknowledgement) for this long is closed
#: (code :data:`IDLE_CLOSE_CODE`, after a one-line note); the page connects again when a control moves
WS_IDLE_SECONDS = 600.0
#: a websocket still not closed this long after its closing began (a peer that reads nothing) is cut
WS_CLOSE_SECONDS = 5.0
#: the close code of a websocket closed for idleness (4000-4999: the application's own)
IDLE_CLOSE_CODE = 4000
#: a kind of log line (its logger and template) is written at most once per this many seconds
LOG_INTERVAL_SECONDS = 10.0
#: at the descriptor limit without the spare descriptor, the accept loop waits this long between attempts
ACCEPT_RETRY_SECONDS = 0.25
#: the answer to a connection refused at the descriptor limit
REFUSAL = (b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain; charset=utf-8\r\n"
           b"Connection: close\r\nRetry-After: 5\r\nContent-Length: 61\r\n\r\n"
           b"refused: the viewer is out of file descriptors; retry shortly\n")
#: accept failures that mean the process (or system) is out of descriptors
_OUT_OF_DESCRIPTORS = (errno.EMFILE, errno.ENFILE)

_log = logging.getLogger("wavlight.viewer")


# ----------------------------------------------------------------------------- log lines
class OneLineLog(logging.Handler):
    """Records as one line each on stderr (``prefix``, the message, an exception's type and
    message), never a traceback; each kind (logger, template) at most once per
    :data:`LOG_INTERVAL_SECONDS`, the next line counting those held back."""

    def __init__(self, prefix: str = "wavlight view", level=logging.WARNING):
        super().__init__(level)
        self.prefix = prefix
        self._last: dict = {}   # (logger, template) -> [time of the last line, lines held back]

    def emit(self, record):
        try:
            key = (record.name, str(record.msg))
            now = time.monotonic()
            last = self._last.get(key)
            if last is not None and now - last[0] < LOG_INTERVAL_SECONDS:
                last[1] += 1
                return
            held = 0 if last is None else last[1]
            if len(self._last) > 1000:   # bounded: kinds are few, but templates could be many
                self._last.clear()
            self._last[key] = [now, 0]
            text = record.getMessage()
            if record.exc_info and record.exc_info[1] is not None:
                text += f": {described(record.exc_info[1])}"
            if held:
                text += f" ({held} more like it in the last {LOG_INTERVAL_SECONDS:g} s)"
            sys.stderr.write(f"{self.prefix}: {' '.join(text.split())}\n")
        except Exception:   # a closed stderr, a message that cannot be formatted
            pass


def one_line_logs(*names):
    """Route the loggers ``names`` (aiohttp's, asyncio's, the viewer's) to one :class:`OneLineLog`
    each, not to the root logger."""
    for name in names:
        logger = logging.getLogger(name)
        if not any(isinstance(h, OneLineLog) for h in logger.handlers):
            logger.addHandler(OneLineLog())
        logger.propagate = False


# ----------------------------------------------------------------------------- the listener
class _Watch:
    """One connection's state: requests under way, whether it is a websocket, its idle timer."""

    __slots__ = ("busy", "timer", "upgraded")

    def __init__(self):
        self.busy, self.upgraded, self.timer = 0, False, None


class Listener:
    """Accept connections on 127.0.0.1 for ``protocol_factory`` (module docstring): refused with
    :data:`REFUSAL` at the descriptor limit, idle ones cut after :data:`HTTP_IDLE_SECONDS`."""

    def __init__(self, protocol_factory):
        self.protocol_factory = protocol_factory
        self.refused = 0                 # connections refused at the descriptor limit, in all
        self._refusing = 0               # ... since the last successful accept
        self._sock = self._loop = self._task = None
        self._spare = None               # the spare descriptor
        self._watched: dict = {}         # transport -> _Watch
        self._pending: set = set()       # connections being set up

    async def start(self, host: str, port: int) -> int:
        """Listen on host:port (0: a free port) and start accepting; the port. OSError when the
        address cannot be bound."""
        self._loop = asyncio.get_running_loop()
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((host, port))
            sock.listen(128)
            sock.setblocking(False)
        except BaseException:
            sock.close()
            raise
        self._sock = sock
        self._take_spare()
        self._task = asyncio.ensure_future(self._accept_loop())
        return sock.getsockname()[1]

    async def close(self):
        """Stop accepting (the connections open stay: the application closes them)."""
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
            self._task = None
        for task in list(self._pending):
            task.cancel()
        await asyncio.gather(*self._pending, return_exceptions=True)
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        for watch in self._watched.values():
            if watch.timer is not None:
                watch.timer.cancel()
        self._watched.clear()
        if self._spare is not None:
            os.close(self._spare)
            self._spare = None

    # -- what the application tells
    def request_started(self, transport):
        """A request began on ``transport``: not idle until it ends."""
        watch = self._watch(transport)
        if watch is not None:
            watch.busy += 1
            self._disarm(watch)

    def request_ended(self, transport):
        """A request ended on ``transport``: idle again (unless it became a websocket)."""
        watch = self._watch(transport)
        if watch is not None:
            watch.busy = max(0, watch.busy - 1)
            if not watch.busy and not watch.upgraded:
                self._arm(transport, watch)

    def upgraded(self, transport):
        """``transport`` is a websocket now: the HTTP idle rule no longer applies."""
        watch = self._watch(transport)
        if watch is not None:
            watch.upgraded = True
            self._disarm(watch)

    def _watch(self, transport):
        """The state of ``transport`` (made here when the application speaks of it before the
        accept loop has registered it: a request may start as soon as the connection is made)."""
        if transport is None or self._loop is None:
            return None
        watch = self._watched.get(transport)
        if watch is None:
            watch = self._watched[transport] = _Watch()
        return watch

    def cut_later(self, transport, seconds: float | None = None):
        """Abort ``transport`` in ``seconds`` (default :data:`WS_CLOSE_SECONDS`) unless it has closed
        by then: a closing that waits for a peer that reads nothing."""
        if transport is None or self._loop is None:
            return
        self._loop.call_later(WS_CLOSE_SECONDS if seconds is None else seconds, transport.abort)

    # -- idle connections
    def _arm(self, transport, watch):
        self._disarm(watch)
        watch.timer = self._loop.call_later(HTTP_IDLE_SECONDS, self._expire, transport)

    @staticmethod
    def _disarm(watch):
        if watch.timer is not None:
            watch.timer.cancel()
            watch.timer = None

    def _expire(self, transport):
        watch = self._watched.get(transport)
        if watch is None or watch.busy or watch.upgraded:
            return
        del self._watched[transport]
        if transport.get_write_buffer_size():
            transport.abort()    # (close() would wait for a peer that reads nothing)
        else:
            transport.close()

    def _forget_closed(self):
        """Drop the closed connections' entries (called now and then, from the accept loop)."""
        for transport in [t for t in self._watched if t.is_closing()]:
            self._disarm(self._watched.pop(transport))

    # -- accepting
    def _take_spare(self):
        if self._spare is None:
            try:
                self._spare = os.open(os.devnull, os.O_RDONLY | os.O_CLOEXEC)
            except OSError:
                self._spare = None

    async def _readable(self):
        """Wait until the listening socket has a connection waiting (or an error)."""
        loop, fd = self._loop, self._sock.fileno()
        ready = loop.create_future()
        loop.add_reader(fd, lambda: ready.done() or ready.set_result(None))
        try:
            await ready
        finally:
            loop.remove_reader(fd)

    async def _accept_loop(self):
        """Accept what waits, then wait for more: a connection at the descriptor limit is refused
        (:meth:`_refuse`); the loop yields after every batch, never spinning (accept fails with
        EMFILE at the limit even with nothing waiting)."""
        while True:
            await self._readable()
            for _ in range(64):
                try:
                    conn, _ = self._sock.accept()
                except (BlockingIOError, InterruptedError):
                    break
                except OSError as e:
                    if e.errno in _OUT_OF_DESCRIPTORS:
                        if self._refuse():
                            continue
                        await asyncio.sleep(ACCEPT_RETRY_SECONDS)
                    elif e.errno in (errno.ECONNABORTED, errno.EPROTO):
                        continue
                    else:   # unexpected: one (rate-limited) line, and a pause against a loop of failures
                        _log.warning("accepting a connection failed: %s", described(e))
                        await asyncio.sleep(ACCEPT_RETRY_SECONDS)
                    break
                if self._refusing:
                    _log.warning("accepting connections again, after refusing %d at the file descriptor limit",
                                 self._refusing)
                    self._refusing = 0
                self._take_spare()
                if len(self._watched) > 64:
                    self._forget_closed()
                task = asyncio.ensure_future(self._serve(conn))
                self._pending.add(task)
                task.add_done_callback(self._pending.discard)
            await asyncio.sleep(0)

    async def _serve(self, conn):
        try:
            conn.setblocking(False)
            transport, _ = await self._loop.connect_accepted_socket(self.protocol_factory, conn)
        except (OSError, RuntimeError, ValueError):   # the connection went away while it was set up
            conn.close()
            return
        watch = self._watch(transport)
        if not watch.busy and not watch.upgraded:
            self._arm(transport, watch)

    def _refuse(self) -> bool:
        """Out of descriptors: the spare descriptor given up to accept the waiting connection,
        answer it :data:`REFUSAL` and close it, and taken again. True when a connection was
        refused (more may wait); False when none waited or there was no spare (then wait)."""
        if self._spare is None:
            self._take_spare()
            if self._spare is None:
                self._note_refusal()
                return False
        os.close(self._spare)
        self._spare = None
        try:
            conn, _ = self._sock.accept()
        except OSError:
            conn = None
        if conn is not None:
            self._note_refusal()
            try:
                conn.setblocking(False)
                conn.send(REFUSAL)
            except OSError:
                pass
            conn.close()
        self._take_spare()
        return conn is not None and self._spare is not None

    def _note_refusal(self):
        self.refused += 1
        self._refusing += 1
        _log.warning("out of file descriptors%s: new connections are refused until some close",
                     _descriptor_limit())


def _descriptor_limit() -> str:
    """The process's soft limit as " (at most N open)", where it is known; else ""."""
    try:
        import resource

        return f" (at most {resource.getrlimit(resource.RLIMIT_NOFILE)[0]} open)"
    except (ImportError, OSError, ValueError):
        return ""
