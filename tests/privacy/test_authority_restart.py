"""A restarted nonce authority hands out the nonces it handed out before (kept in its
key directory), so parties that took envelopes before the restart and parties that take
them after it agree: no envelope refused, no message refused, the same emitter ids."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.errors import KeyStoreError
from rfsas_hw.link import Receiver, ReceiverConfig, SafetyMessage
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.preauth import PreauthKeys, seal
from rfsas_hw.privacy import MacHasher
from rfsas_hw.privacy.epochs import NS_PER_S, EpochSchedule
from rfsas_hw.privacy.nonce_state import STATE_FILE, load_nonces
from rfsas_hw.privacy.nonces import NonceAuthority, NonceStore
from rfsas_hw.records import BearingBatch, Pose

SCHED = EpochSchedule(60.0, 5.0)
NOW = 1_763_800_030 * NS_PER_S
MACS = np.array([0x3C22_FB4E_9107, 0x0200_0000_0001], np.uint64)


def stores(tmp_path: Path) -> tuple[KeyStore, KeyStore, KeyStore]:
    auth = KeyStore.create(tmp_path / "auth", "authority", "rsu-0")
    sensor = KeyStore.create(tmp_path / "rsu-1", "sensor")
    backend = KeyStore.create(tmp_path / "obu-1", "backend")
    for party in (sensor, backend):
        auth.trust.enroll(party.card)
        party.trust.enroll(auth.card)
    backend.trust.enroll(sensor.card)
    return auth, sensor, backend


def hand_out(authority: NonceAuthority, store: NonceStore) -> None:
    """Every envelope due now, as the distributor sends them (raises if one is refused)."""
    for epoch in authority.due(NOW):
        store.accept_envelope(authority.seal(store.receiver_id, epoch), NOW)


def messages(sensor: KeyStore, nonces: NonceStore, n: int) -> list[bytes]:
    signer, keys = sensor.signer(), PreauthKeys(nonces)
    epoch = SCHED.epoch_of(NOW)
    out = []
    for seq in range(n):
        t_ns = NOW - 50_000_000 + seq * 1000
        batch = BearingBatch(
            signer.sender_id,
            np.array([t_ns], np.int64),
            np.array([float(seq)]),
            np.array([2.0]),
            np.array([20.0]),
            np.array([6], np.int16),
            np.array([seq + 1], np.uint64),
        )
        msg = SafetyMessage(signer.sender_id, Pose(0, 0, 0), t_ns // 1000, seq, epoch, batch)
        key = keys.key_for(signer.sender_id, epoch)
        assert key is not None
        out.append(seal(signer, msg, key))
    return out


def test_a_restarted_authority_does_not_split_the_deployment(tmp_path: Path) -> None:
    auth, sensor, backend = stores(tmp_path)
    before = auth.nonce_authority(SCHED)
    sensor_nonces = sensor.nonce_store(SCHED, clock=lambda: NOW)
    hand_out(before, sensor_nonces)  # the sensor took its nonces before the restart
    ids_before = MacHasher(sensor_nonces).hash_batch(MACS, np.full(2, NOW, np.int64))
    del before  # the authority process stops ...
    after = auth.nonce_authority(SCHED)  # ... and comes back on its key directory
    backend_nonces = backend.nonce_store(SCHED, clock=lambda: NOW)
    hand_out(after, backend_nonces)  # the backend starts after the restart
    hand_out(after, sensor_nonces)  # the sensor is sent the envelopes again: not refused
    rx = Receiver(
        backend.trust,
        backend_nonces,
        ReceiverConfig(epoch_s=60.0, grace_s=5.0, accept_v1=False),
        clock=lambda: NOW,
    )
    verified = [rx.feed(d, NOW) for d in messages(sensor, sensor_nonces, 20)]
    assert rx.stats.rejected_total == 0, rx.stats.rejected
    assert all(v is not None for v in verified) and rx.stats.verified == 20
    # and the two sides' emitter ids are the same, so their bearings associate
    ids_after = MacHasher(backend_nonces).hash_batch(MACS, np.full(2, NOW, np.int64))
    assert ids_after.tolist() == ids_before.tolist()


def test_the_state_file_is_private_and_bounded(tmp_path: Path) -> None:
    auth, _, _ = stores(tmp_path)
    authority = auth.nonce_authority(SCHED)
    for epoch in range(100, 120):
        authority.nonce_for(epoch)
    path = auth.path / STATE_FILE
    assert path.stat().st_mode & 0o777 == 0o600
    kept = load_nonces(path, "rsu-0")
    assert sorted(kept) == list(range(112, 120))  # the 8 epochs it keeps, no more
    assert kept[119] == authority.nonce_for(119)


def test_a_bad_state_file_is_named(tmp_path: Path) -> None:
    auth, _, _ = stores(tmp_path)
    auth.nonce_authority(SCHED).nonce_for(5)
    path = auth.path / STATE_FILE
    with pytest.raises(KeyStoreError, match="not the nonce state of authority 'rsu-9'"):
        load_nonces(path, "rsu-9")
    path.write_text(path.read_text() + "6 abcd\n")
    with pytest.raises(KeyStoreError, match=r"nonces.state: line 3: .*4 hex digits"):
        auth.nonce_authority(SCHED)
    os.chmod(path, 0o644)
    with pytest.raises(KeyStoreError, match="readable by other users"):
        auth.nonce_authority(SCHED)


def test_a_failed_write_is_logged_and_counted(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    auth, _, _ = stores(tmp_path)
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    authority = NonceAuthority("rsu-0", auth.kx_private(), SCHED, state=tmp_path / "ok.state")
    authority.state = blocker / "nonces.state"  # its directory is now a file: writes fail
    with caplog.at_level(logging.ERROR, logger="rfsas_hw.privacy.nonces"):
        nonce = authority.nonce_for(7)
    assert authority.nonce_for(7) == nonce and authority.state_errors == 1
    assert "nonce of epoch 7 not persisted" in caplog.text and "a-file" in caplog.text
