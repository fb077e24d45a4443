"""Counting what a receiver took: every nonce envelope is counted as one, whatever became
of it, so ``datagrams - envelopes`` is exactly the safety messages received (a district
run's "lost" = sent − received depends on it)."""

from __future__ import annotations

from cryptography.hazmat.primitives.asymmetric import x25519
from linkhelp import NOW_NS, SCHEDULE, Queued, message

from rfsas_hw.link import Receiver, ReceiverConfig, Signer, TrustedKeys
from rfsas_hw.privacy.nonces import NonceAuthority, NonceStore


def test_envelopes_are_counted_whatever_became_of_them(signer: Signer, trust: TrustedKeys) -> None:
    auth_key, my_key = x25519.X25519PrivateKey.generate(), x25519.X25519PrivateKey.generate()
    authority = NonceAuthority("auth-0", auth_key, SCHEDULE)
    authority.enroll("obu-9", my_key.public_key())
    authority.enroll("obu-8", x25519.X25519PrivateKey.generate().public_key())
    store = NonceStore("obu-9", my_key, {"auth-0": auth_key.public_key()}, SCHEDULE, clock=None)
    epoch = SCHEDULE.epoch_of(NOW_NS)
    messages = [signer.encode(message(seq=s, seed=s)) for s in range(300)]
    ours = authority.seal("obu-9", epoch)
    theirs = authority.seal("obu-8", epoch)  # for another receiver: nonce_rejected
    # one batch of more than the backlog (256): checked newest first, and after the first
    # signature check everything else that would cost cryptography is shed, the
    # envelopes among them (their opening costs key agreements)
    queued = [*messages[:100], ours, *messages[100:200], theirs, *messages[200:]]
    config = ReceiverConfig(shed_after_s=1e-9)
    r = Receiver(trust, store, config, transport=Queued(queued), clock=lambda: NOW_NS)
    got = r.receive(0)
    st = r.stats
    assert st.datagrams == 302 and st.envelopes == 2
    assert st.rejected["overload"] > 0
    # the envelopes were shed, not taken or refused by the store: a count that subtracts
    # only those would take them for safety messages
    assert st.nonces == 0 and st.rejected["nonce_rejected"] == 0
    assert st.datagrams - st.envelopes == len(messages)
    assert len(got) == st.verified >= 1

    # one at a time nothing is shed: taken or refused by the store, each is counted (a
    # datagram with the envelope's type is one, even when the store cannot open it)
    r = Receiver(trust, store, ReceiverConfig(), clock=lambda: NOW_NS)
    for d in (ours, messages[0], theirs, b"RF\x01\x02" + bytes(10)):
        r.feed(d, NOW_NS)
    st = r.stats
    assert st.nonces == 1 and st.rejected["nonce_rejected"] == 2 and st.verified == 1
    assert st.envelopes == 3 and st.datagrams == 4
    assert r.counters()["envelopes"] == 3
