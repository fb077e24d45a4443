"""A real mosquitto for fleet tests: mutual TLS and ACLs from ``rfsas broker config``.

The broker runs on a free loopback port, started and stopped by the fixture. Tests
skip with the reason when the ``mosquitto`` program is not installed (Debian
package ``mosquitto``; the CI script installs it).
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

# pytest runs with --import-mode=importlib: the helpers of this folder go on the path
sys.path.insert(0, str(Path(__file__).parent))

from brokerhelp import MOSQUITTO, Broker, Deployment, _spawn, free_tcp_port, make_deployment


@pytest.fixture(scope="module")
def deployment(tmp_path_factory: pytest.TempPathFactory) -> Deployment:
    return make_deployment(tmp_path_factory.mktemp("fleet"), free_tcp_port())


@pytest.fixture
def broker(deployment: Deployment, tmp_path: Path) -> Iterator[Broker]:
    if MOSQUITTO is None:
        pytest.skip("mosquitto is not installed (Debian package mosquitto)")
    log = tmp_path / "mosquitto.log"
    b = Broker(deployment.files, _spawn(deployment.files, log), log)
    yield b
    if b.proc.poll() is None:
        b.proc.terminate()
        try:
            b.proc.wait(5)
        except subprocess.TimeoutExpired:
            b.proc.kill()
            b.proc.wait(5)
