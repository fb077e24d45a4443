"""The broker knows a client by its certificate's name: check it against the key id at start.

The broker (``use_identity_as_username``) takes a client certificate's common
name as the user its ACL judges. A sensor started with another identity's
certificate signs as itself but publishes as someone else, and the broker
drops every message without a word (QoS 0 has no acknowledgement). So a
command checks, before it connects, that every ``mqtts://`` URL's ``cert=``
names the identity of its ``--keys``.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from cryptography import x509
from cryptography.x509.oid import NameOID

from rfsas_hw.errors import ConfigError
from rfsas_hw.link.mqtt import parse_mqtt_url


def common_name(path: str | Path) -> str:
    """The subject common name of the PEM certificate at ``path``.

    Raises:
        ConfigError: the file cannot be read, is not a PEM certificate, or has no
            common name.
    """
    p = Path(path)
    try:
        cert = x509.load_pem_x509_certificate(p.read_bytes())
    except OSError as err:
        raise ConfigError(f"{p}: cannot read: {err.strerror or err}") from err
    except ValueError as err:
        raise ConfigError(f"{p}: not a PEM certificate: {err}") from err
    names = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    if not names:
        raise ConfigError(f"{p}: the certificate has no common name")
    value = names[0].value
    return value if isinstance(value, str) else value.decode("utf-8", "replace")


def check_certificate_names(urls: Iterable[str], ident: str, option: str) -> None:
    """Refuse an MQTT URL whose client certificate is issued to another identity.

    URLs of other schemes (``udp://``) and MQTT URLs without ``cert=`` pass.

    Raises:
        ConfigError: a certificate names another identity than ``ident`` (the
            message names the option, the file and both names).
        LinkError: a URL cannot be parsed.
    """
    for url in urls:
        if not url.startswith(("mqtt://", "mqtts://")):
            continue
        endpoint = parse_mqtt_url(url)
        if endpoint.cert is None:
            continue
        name = common_name(endpoint.cert)
        if name != ident:
            raise ConfigError(
                f"{option}: the certificate {endpoint.cert} is issued to {name!r}, but the "
                f"key directory is {ident!r}; the broker would take every message as "
                f"{name!r}'s and its ACL drop them (use the certificate issued to {ident!r})"
            )
