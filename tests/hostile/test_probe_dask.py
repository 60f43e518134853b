"""`--dask` at network services that misbehave.

Whatever listens (or does not) at the --dask address, the experiment fails within the stated
time (DASK_TIMEOUT, 20 s, or ``dask_timeout``) with one line naming the address: nothing
listening, a service that accepts and never answers (distributed's own connect would wait far
past the client's timeout), a service that answers another protocol (distributed alone would
try to allocate 3 EiB for it), a greeting cut short, a scheduler without workers, a scheduler
that stops answering in the middle of the runs (distributed alone would wait without end) or
one that loses its workers.

The servers here listen on 127.0.0.1 only, on a port the system picks, and stop by themselves
(a deadline of 30 s, and at the end of each test). The timeouts are set to 2 s.
"""
from __future__ import annotations

import socket
import struct
import threading
import time

import pytest
from click.testing import CliRunner

from wavlight import cluster
from wavlight.cli.main import main
from wavlight.errors import WavlightError
from wavlight.evaluation import experiment

from test_probe_experiment import write_spec

T = 2.0


class Server:
    """A TCP server on 127.0.0.1 that runs ``behave(conn)`` for each connection, for at most 30 s."""

    def __init__(self, behave):
        self.behave, self.sock = behave, socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.sock.settimeout(0.2)
        self.address = f"tcp://127.0.0.1:{self.sock.getsockname()[1]}"
        self.stop, self.conns = threading.Event(), []
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        end = time.monotonic() + 30
        while not self.stop.is_set() and time.monotonic() < end:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                continue
            self.conns.append(conn)
            threading.Thread(target=self._one, args=(conn,), daemon=True).start()
        self.close()

    def _one(self, conn):
        try:
            self.behave(conn, self.stop)
        except OSError:
            pass

    def close(self):
        self.stop.set()
        for c in self.conns:
            c.close()
        self.sock.close()


def silent(conn, stop):
    stop.wait(30)


def http(conn, stop):
    conn.sendall(b"HTTP/1.1 200 OK\r\nContent-Length: 5\r\n\r\nhello")
    stop.wait(30)


def greeting_cut_short(conn, stop):
    conn.sendall(struct.pack("<Q", 58) + b"\x00" * 10)
    stop.wait(30)


def junk_greeting(conn, stop):
    conn.sendall(struct.pack("<Q", 16) + b"\xff" * 16)
    stop.wait(30)


def slow_drip(conn, stop):   # one byte a second: each read is quick, the whole never comes
    for _ in range(30):
        if stop.wait(1.0):
            return
        conn.sendall(b"\x00")


SERVERS = {   # behaviour: words of the message
    "accepts and never answers": (silent, "no answer from a Dask scheduler within 2 s"),
    "answers HTTP": (http, "does not speak Dask's protocol"),
    "greeting cut short": (greeting_cut_short, "no answer from a Dask scheduler within 2 s"),
    "greeting of junk": (junk_greeting, "does not speak Dask's protocol"),
    "one byte a second": (slow_drip, "no answer from a Dask scheduler within 2 s"),
}


@pytest.fixture
def server(request):
    servers = []

    def start(behave):
        servers.append(Server(behave))
        return servers[-1]
    yield start
    for s in servers:
        s.close()


@pytest.mark.slow
@pytest.mark.parametrize("case", list(SERVERS))
def test_a_misbehaving_service_fails_in_time_naming_the_address(server, case, tmp_path):
    """Whatever the service does, one WavlightError naming the address comes within the
    timeout (+1.5 s), and nothing is written to the output folder."""
    behave, words = SERVERS[case]
    s = server(behave)
    spec = write_spec(tmp_path)
    t = time.perf_counter()
    with pytest.raises(WavlightError) as e:
        experiment.run_experiment(spec, tmp_path / "out", dask_address=s.address, dask_timeout=T)
    assert time.perf_counter() - t < T + 1.5
    assert s.address in str(e.value) and words in str(e.value), str(e.value)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("address, words", [
    ("tcp://127.0.0.1:1", "cannot connect"),                       # nothing listens
    ("tcp://127.0.0.1:99999", "cannot connect"),                   # no such port
    ("tcp://no-such-host.invalid:8786", "cannot connect"),         # no such host
    ("127.0.0.1:8786", "expected a scheduler address"),            # no scheme
    ("tcp://127.0.0.1", "expected a scheduler address"),           # no port
    ("tcp://127.0.0.1:87 86", "expected a scheduler address"),
    ("x" * 10_000, "expected a scheduler address"),                # shown short
])
def test_addresses_that_lead_nowhere(tmp_path, address, words):
    """An address that leads nowhere is one short line naming the address (cut to ~80
    characters when it is huge), within the timeout."""
    spec = write_spec(tmp_path)
    t = time.perf_counter()
    with pytest.raises(WavlightError, match=words) as e:
        experiment.run_experiment(spec, tmp_path / "out", dask_address=address, dask_timeout=T)
    assert time.perf_counter() - t < T + 1.5 and len(str(e.value)) < 300


def test_the_cli_fails_in_the_stated_time(server, tmp_path, monkeypatch):
    """`wavlight experiment SPEC --dask ADDRESS` at a silent service exits 2 with one line
    naming the address and the time waited (DASK_TIMEOUT, 2 s here)."""
    monkeypatch.setattr(experiment, "DASK_TIMEOUT", T)
    s = server(silent)
    spec = write_spec(tmp_path)
    t = time.perf_counter()
    r = CliRunner().invoke(main, ["experiment", str(spec), "-o", str(tmp_path / "out"), "-q", "--dask", s.address])
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert r.exit_code == 2 and len(lines) == 1 and s.address in lines[0] and "2 s" in lines[0], r.output
    assert time.perf_counter() - t < T + 2


def test_a_scheduler_without_workers_fails_in_time(tmp_path):
    """A real scheduler with no worker is one line within the timeout, not a wait for a worker
    that never comes."""
    distributed = pytest.importorskip("distributed")
    spec = write_spec(tmp_path)
    with distributed.LocalCluster(n_workers=0, processes=False, protocol="tcp://", host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        t = time.perf_counter()
        with pytest.raises(WavlightError, match="the scheduler has no workers") as e:
            experiment.run_experiment(spec, tmp_path / "out", dask_address=cluster.scheduler_address,
                                      dask_timeout=T)
        assert time.perf_counter() - t < T + 3 and cluster.scheduler_address in str(e.value)


class _FakeClient:
    def __init__(self, answer):
        self.answer, self.scheduler = answer, type("S", (), {"identity": None})()

    def sync(self, fn, callback_timeout=None):
        if isinstance(self.answer, BaseException):
            raise self.answer
        return self.answer


def test_a_scheduler_that_stops_answering_mid_run_is_an_error(monkeypatch):
    """While runs are pending and none finishes for the timeout, the scheduler must answer who
    it is within the timeout; silence (a frozen scheduler whose connection stays open) is one
    line naming the address, where distributed's as_completed alone would wait without end."""
    distributed = pytest.importorskip("distributed")

    def never(pending, timeout=None, return_when=None):
        raise TimeoutError
    monkeypatch.setattr(distributed, "wait", never)
    it = cluster.finished(_FakeClient(TimeoutError("no reply")), [object()], "tcp://h:1", T)
    with pytest.raises(WavlightError, match=r"tcp://h:1: the scheduler stopped answering"):
        next(it)


def test_a_scheduler_that_lost_its_workers_mid_run_is_an_error(monkeypatch):
    """A scheduler that answers but has had no worker for two timeouts is one line, so that the
    pending runs do not wait for a worker without end."""
    distributed = pytest.importorskip("distributed")

    def never(pending, timeout=None, return_when=None):
        raise TimeoutError
    monkeypatch.setattr(distributed, "wait", never)
    it = cluster.finished(_FakeClient({"workers": {}}), [object()], "tcp://h:1", T)
    with pytest.raises(WavlightError, match=r"tcp://h:1: the scheduler has had no workers for 4 s"):
        next(it)
