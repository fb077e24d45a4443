"""A receiver whose every subscription the broker refuses fails at start, naming the
refusal, instead of listening to nothing. (mosquitto grants a subscription its ACL
will not deliver to; other brokers answer 0x87 in the SUBACK, as this one does.)"""

from __future__ import annotations

import socket
import threading

import pytest

from rfsas_hw.errors import LinkError
from rfsas_hw.link.mqtt import open_mqtt

NOT_AUTHORIZED = 0x87


def _read_packet(conn: socket.socket) -> bytes:
    """One MQTT packet: fixed header, remaining length (varint), body."""
    head = conn.recv(1)
    length, shift = 0, 0
    while True:
        byte = conn.recv(1)[0]
        length |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            break
    body = b""
    while len(body) < length:
        chunk = conn.recv(length - len(body))
        if not chunk:
            break
        body += chunk
    return head + body


def _refusing_broker(server: socket.socket, done: threading.Event) -> None:
    server.settimeout(10)
    try:
        conn, _ = server.accept()
    except OSError:
        return
    with conn:
        conn.settimeout(10)
        _read_packet(conn)  # CONNECT
        conn.sendall(bytes([0x20, 3, 0, 0, 0]))  # CONNACK: success, no properties
        subscribe = _read_packet(conn)
        packet_id = subscribe[1:3]
        conn.sendall(bytes([0x90, 4]) + packet_id + bytes([0, NOT_AUTHORIZED]))
        done.wait(10)


def test_a_receiver_the_broker_lets_hear_nothing_fails_at_start() -> None:
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    done = threading.Event()
    thread = threading.Thread(target=_refusing_broker, args=(server, done), daemon=True)
    thread.start()
    port = server.getsockname()[1]
    try:
        with pytest.raises(LinkError, match="refused every subscription"):
            open_mqtt(f"mqtt://127.0.0.1:{port}?connect_s=2", "recv")
    finally:
        done.set()
        thread.join(10)
        server.close()
