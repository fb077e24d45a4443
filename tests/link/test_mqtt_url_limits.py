"""MQTT URLs with values the network thread cannot live with, or that would make a
client hear nothing, are refused while parsing, with the option named."""

from __future__ import annotations

from pathlib import Path

import pytest

from rfsas_hw.errors import LinkError
from rfsas_hw.link.mqtt import open_mqtt, parse_mqtt_url


@pytest.mark.parametrize(
    ("query", "words"),
    [
        ("keepalive=1e12", "keepalive"),
        ("client_id=" + "x" * 70_000, "client_id"),
        ("client_id=a%0Ab", "client_id"),
        ("connect_s=1e9", "connect_s"),
        ("queue=1e15", "queue"),
        ("tiles=12021301230123012", "deeper than"),  # 17 digits: the topics have 16 levels
        ("advisories=12021301230123012", "deeper than"),
    ],
)
def test_values_out_of_range_are_refused(query: str, words: str) -> None:
    with pytest.raises(LinkError, match=words):
        parse_mqtt_url(f"mqtt://127.0.0.1:1883?{query}")


def test_port_zero_is_refused_not_replaced_by_the_default() -> None:
    with pytest.raises(LinkError, match="port 0"):
        parse_mqtt_url("mqtt://127.0.0.1:0")
    assert parse_mqtt_url("mqtt://127.0.0.1").port == 1883


@pytest.mark.parametrize("option", ["sub=a/b", "tiles=1202", "nonces=rsu-1", "queue=10"])
def test_receiver_options_on_a_send_url_are_refused(option: str) -> None:
    # port 1: nothing listens, so a URL that got past the check would fail otherwise
    with pytest.raises(LinkError, match="receiving URLs only"):
        open_mqtt(f"mqtt://127.0.0.1:1?{option}", "send")


def test_a_tls_key_others_can_read_is_refused(tmp_path: Path) -> None:
    files = {name: tmp_path / f"{name}.pem" for name in ("ca", "cert", "key")}
    for path in files.values():
        path.write_text("-----BEGIN X-----\n")
    files["key"].chmod(0o644)
    query = "&".join(f"{name}={path}" for name, path in files.items())
    with pytest.raises(LinkError, match="readable by others"):
        parse_mqtt_url(f"mqtts://127.0.0.1:8883?{query}")
    files["key"].chmod(0o600)
    assert parse_mqtt_url(f"mqtts://127.0.0.1:8883?{query}").key == files["key"]
