"""Fuzzing the capture reader and frame decoder with mutated small captures.

``RFSAS_FUZZ_CASES`` sets the number of mutated captures (default 100,000;
``make fuzz`` runs 1,000,000). Each case is parsed in-process; the reader may
refuse a file that is not a capture (one :class:`CaptureFormatError`), but
nothing may crash, hang or lose track of frame numbers. Every 50th case is
also decoded along the numpy path and must agree with the per-frame walk.
"""

from __future__ import annotations

import os
import random
import struct
from pathlib import Path

import numpy as np
import pytest
import rt_writer as w
from bytefuzz import Mutation, delete, flip_bits, insert, mutate, pack_u32, set_byte, truncate

from rfsas_hw.errors import CaptureFormatError
from rfsas_hw.sources.frames import FrameDecoder, FrameSpans
from rfsas_hw.sources.pcapfile import CaptureParser

CASES = int(os.environ.get("RFSAS_FUZZ_CASES", "100000"))
SEED = int(os.environ.get("RFSAS_FUZZ_SEED", "20240601"))


def seeds(data_dir: Path) -> list[bytes]:
    """Small, valid captures covering both containers, both byte orders and odd headers."""
    meshid = (data_dir / "ieee802.11_meshid.pcap").read_bytes()
    first = meshid[: 24 + 16 + 239]
    vendor = w.build(
        [
            w.RtNamespace({0: bytes(8), 1: b"\x10", 5: w.value(5, -40)}),
            w.RtNamespace({5: w.value(5, -41), 11: w.value(11, 0)}),
            w.VendorNs(0x00AABB, 1, b"\x01\x02\x03", 0x5),
        ]
    ) + w.dot11(seq=9, fcs=True)
    tlv = struct.pack("<BBHI", 0, 0, 16, (1 << 1) | (1 << 28)) + b"\x00" + bytes(7) + w.dot11()
    frame = meshid[24 + 16 : 24 + 16 + 239]
    return [
        first,
        (data_dir / "bad_rsn_parsing_overrides_ssid.pcap").read_bytes(),
        (data_dir / "meshid_big_endian.pcap").read_bytes()[: 24 + 16 + 239],
        w.pcap([(1_000, vendor), (2_000, tlv)]),
        w.pcapng([(127, 9)], [(0, 5, frame)]),
        w.pcapng([(127, None), (105, 0x86)], [(1, 7, frame[56:]), (0, 9, vendor)], big_endian=True),
    ]


MUTATIONS: list[Mutation] = [set_byte(header=1 << 30), flip_bits, pack_u32, truncate]
MUTATIONS += [delete, insert]


def decode_all(data: bytes, decoder: FrameDecoder, other: FrameDecoder | None) -> None:
    parser = CaptureParser("fuzz")
    parser.feed(data)
    last_frame = 0
    for _ in range(len(data) + 8):
        try:
            chunk = parser.next_chunk(final=True, max_frames=7)
        except CaptureFormatError:
            return
        if chunk is None:
            return
        spans = FrameSpans(
            chunk.start, chunk.caplen, chunk.t_ns, chunk.frame_no, chunk.file_offset, chunk.linktype
        )
        numbers = chunk.frame_no.tolist() + [p.frame_no for p in chunk.problems if p.frame_no]
        assert len(set(numbers)) == len(numbers), "a frame number was used twice"
        assert all(n > last_frame for n in numbers), "frame numbers went backwards"
        last_frame = max(numbers, default=last_frame)
        assert (chunk.start >= 0).all() and (chunk.start + chunk.caplen <= len(chunk.buf)).all()
        result = decoder.decode(chunk.buf, spans)
        for problem in result.problems:
            assert problem.frame_no > 0 and problem.detail
        if other is not None:
            again = other.decode(chunk.buf, spans)
            assert [p.detail for p in again.problems] == [p.detail for p in result.problems]
            assert again.dropped == result.dropped
            np.testing.assert_array_equal(again.table.frame_no, result.table.frame_no)
            np.testing.assert_array_equal(again.table.mac, result.table.mac)
            np.testing.assert_array_equal(again.table.chain_dbm, result.table.chain_dbm)
            np.testing.assert_array_equal(again.table.tsft_us, result.table.tsft_us)
    raise AssertionError("the parser did not finish: possible hang")


@pytest.mark.fuzz
def test_mutated_captures_never_crash(data_dir: Path) -> None:
    rng = random.Random(SEED)
    bases = seeds(data_dir)
    walk = FrameDecoder(n_antennas=2, vector_min=1 << 30)
    vector = FrameDecoder(n_antennas=2, vector_min=0)
    for case in range(CASES):
        data = mutate(rng, rng.choice(bases), MUTATIONS, rounds=(1, 1, 1, 2, 3))
        try:
            decode_all(data, walk, vector if case % 50 == 0 else None)
        except Exception as err:
            raise AssertionError(f"case {case} (seed {SEED}) failed on {data.hex()}") from err
