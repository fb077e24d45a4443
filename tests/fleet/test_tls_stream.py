"""TLS through memory buffers: every record that has arrived comes back from one
read, writes reach the peer, the socket's non-blocking and timeout meanings hold."""

from __future__ import annotations

import socket
import ssl
import threading
from collections.abc import Callable, Iterator

import pytest
from brokerhelp import Deployment

from rfsas_hw.link.tls_stream import TlsStream

RECORDS = 300
RECORD = bytes(range(100))


def _contexts(deployment: Deployment) -> tuple[ssl.SSLContext, ssl.SSLContext]:
    files = deployment.files
    server = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    server.load_cert_chain(
        files.root / "broker" / "server.crt", files.root / "broker" / "server.key"
    )
    server.load_verify_locations(cafile=str(files.ca_cert))
    server.verify_mode = ssl.CERT_REQUIRED
    client = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    client.load_verify_locations(cafile=str(files.ca_cert))
    pair = files.client("be-a")
    client.load_cert_chain(str(pair.cert), str(pair.key))
    return server, client


@pytest.fixture
def serve(deployment: Deployment) -> Iterator[Callable[..., tuple[TlsStream, threading.Thread]]]:
    server_ctx, client_ctx = _contexts(deployment)
    listener = socket.create_server(("127.0.0.1", 0))
    threads: list[threading.Thread] = []

    def start(body: Callable[[ssl.SSLSocket], None]) -> tuple[TlsStream, threading.Thread]:
        def run() -> None:
            conn, _ = listener.accept()
            with server_ctx.wrap_socket(conn, server_side=True) as tls:
                body(tls)

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        threads.append(thread)
        raw = socket.create_connection(listener.getsockname(), timeout=5)
        return TlsStream(raw, client_ctx, "127.0.0.1", 5.0), thread

    yield start
    for thread in threads:
        thread.join(5)
    listener.close()


def test_records_that_have_arrived_come_back_from_one_read(
    serve: Callable[..., tuple[TlsStream, threading.Thread]],
) -> None:
    sent = threading.Event()
    echoed: list[bytes] = []

    def body(tls: ssl.SSLSocket) -> None:
        for _ in range(RECORDS):
            tls.sendall(RECORD)  # one record each
        sent.set()
        echoed.append(tls.recv(100))

    stream, thread = serve(body)
    assert sent.wait(5)
    stream.setblocking(False)
    got, reads = b"", 0
    stream.settimeout(2.0)
    while len(got) < RECORDS * len(RECORD):
        got += stream.recv()
        reads += 1
    assert got == RECORD * RECORDS
    assert reads < RECORDS // 10  # not one read per record
    assert stream.pending() == 0
    stream.sendall(b"pong")
    thread.join(5)
    assert echoed == [b"pong"]
    assert stream.recv() == b""  # the server closed
    stream.close()


def test_a_read_that_empties_the_socket_says_so(
    serve: Callable[..., tuple[TlsStream, threading.Thread]],
) -> None:
    sent = threading.Event()
    done = threading.Event()

    def body(tls: ssl.SSLSocket) -> None:
        for _ in range(5):
            tls.sendall(RECORD)
        sent.set()
        done.wait(5)

    stream, thread = serve(body)
    try:
        assert sent.wait(5)
        stream.settimeout(2.0)
        got = b""
        while len(got) < 5 * len(RECORD):
            got += stream.recv()
        assert got == RECORD * 5
        # everything that came was read, and the flag says so: a reader that stops here
        # loses nothing (asking again finds nothing)
        assert stream.drained
        stream.setblocking(False)
        with pytest.raises(ssl.SSLWantReadError):
            stream.recv()
    finally:
        done.set()
        thread.join(5)
        stream.close()


def test_non_blocking_and_timed_reads_say_nothing_has_arrived(
    serve: Callable[..., tuple[TlsStream, threading.Thread]],
) -> None:
    done = threading.Event()
    stream, _ = serve(lambda tls: done.wait(5))
    stream.setblocking(False)
    with pytest.raises(ssl.SSLWantReadError):
        stream.recv()
    stream.settimeout(0.05)
    with pytest.raises(TimeoutError):
        stream.recv()
    assert stream.raw.fileno() == stream.fileno()
    done.set()
    stream.close()


def test_a_server_the_client_does_not_trust_fails_the_handshake(deployment: Deployment) -> None:
    _, client_ctx = _contexts(deployment)
    other = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    # the client's own certificate is not a server certificate its CA vouches for by name
    pair = deployment.files.client("be-a")
    other.load_cert_chain(str(pair.cert), str(pair.key))
    listener = socket.create_server(("127.0.0.1", 0))

    def run() -> None:
        conn, _ = listener.accept()
        try:
            other.wrap_socket(conn, server_side=True).close()
        except (ssl.SSLError, OSError):
            conn.close()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    raw = socket.create_connection(listener.getsockname(), timeout=5)
    with pytest.raises(ssl.SSLError):
        TlsStream(raw, client_ctx, "127.0.0.1", 5.0)
    raw.close()
    thread.join(5)
    listener.close()
