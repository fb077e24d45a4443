"""Frames per second from a radiotap pcap to per-chain signal: rfsas-hw next to the usual tools.

    python bench/bench_capture.py [N]

Writes a pcap of N frames (default 500,000) with the layouts real captures
mix: mac80211 two-chain headers (most frames), three chains, a single
namespace without chains, vendor namespaces (walked frame by frame), and ACKs
(no transmitter). Then, from the same file:

- rfsas-hw ``pcap:`` source: pcap → ObservationBatch (time, MAC, channel,
  per-chain dBm, seq, kind, flags);
- tshark extracting the same fields (``-T fields``) — on a subset;
- scapy ``RawPcapReader`` (records only, no radiotap decoding);
- rfsas-hw's per-frame walk (``radiotap.parse``) over those raw records;
- scapy full dissection (``PcapReader``), which does not decode the chains —
  on a small subset.

A second table times the two ways pcap records are found — the numpy walk
over large buffers (``pcapfile.find_pcap_records``) and the record-by-record
loop — on that capture (small frames) and on one of N/4 frames with a
realistic size mix (data frames of 60–1,500 bytes), parsing only and from
pcap to observations. The walk is kept because it wins on both.

A third table times small batches (live capture drains a few frames at a
time) decoded with the numpy gathers and with the per-frame walk; the
decoder's ``DEFAULT_VECTOR_MIN`` is where they cost the same.

Rates are frames per CPU second of the process doing the work (tshark's
CPU time is read from the child's resource usage), so a busy shared machine
skews them less than wall time would. Ratios are from this one run.
"""

from __future__ import annotations

import resource
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import rfsas_hw.sources
from rfsas_hw.sources import pcapfile, radiotap
from rfsas_hw.sources.frames import DEFAULT_VECTOR_MIN, FrameDecoder, FrameSpans

GOAL_PER_S = 1_000_000
GOAL_VS_TSHARK = 30.0
TSHARK_FIELDS = [
    "frame.time_epoch",
    "wlan.ta",
    "wlan.seq",
    "wlan.fc.type_subtype",
    "radiotap.channel.freq",
    "radiotap.dbm_antsignal",
    "radiotap.antenna",
]


def _header(words: list[int], body: bytes) -> bytes:
    raw = struct.pack("<BBH", 0, 0, 4 + 4 * len(words) + len(body))
    return raw + b"".join(struct.pack("<I", w) for w in words) + body


def templates() -> list[tuple[float, bytes, bytes]]:
    """(share of frames, radiotap header, 802.11 frame) for each layout in the mix."""
    tsft = struct.pack("<Q", 9_526_800_862)
    chan = struct.pack("<HH", 5745, 0x0140)
    # mac80211, two chains: TSFT, Flags, Rate, Channel, dBm, RX flags, then chain namespaces.
    two = _header(
        [0xA000402F, 0xA0000820, 0x00000820],
        tsft + b"\x10\x0c" + chan + b"\xde\x00" + b"\x00\x00" + b"\xd9\x00\xde\x01",
    )
    three = _header(
        [0xA000402F, 0xA0000820, 0xA0000820, 0x00000820],
        bytes(4) + tsft + b"\x10\x0c" + chan + b"\xce\x00\x00\x00" + b"\xb2\x00\xbd\x01\xce\x02",
    )
    single = _header([0x0000086E], b"\x10\x0c" + chan + b"\xd0\xa0\x01")
    # A vendor namespace between namespace 0 and the chain: offsets vary, walked per frame.
    vendor = _header(
        [0xC000002E, 0xA0000001, 0x00000820],
        b"\x10\x0c" + chan + b"\xd3\x00" + b"\x00\x11\x22\x01\x04\x00" + b"\x01\x02\x03\x04"
        + b"\xd1\x00",
    )  # fmt: skip
    beacon = struct.pack("<HH", 0x0080, 0) + b"\xff" * 6 + bytes(6) + b"\xff" * 6 + bytes(2)
    beacon += bytes(40) + b"\x00\x00\x00\x00"  # body + FCS
    ack = struct.pack("<HH", 0x00D4, 0) + bytes(6) + b"\x00\x00\x00\x00"
    return [
        (0.80, two, beacon),
        (0.08, three, beacon),
        (0.05, single, beacon),
        (0.02, vendor, beacon),
        (0.05, two, ack),
    ]


def write_capture(path: Path, n: int) -> None:
    """A pcap of ``n`` frames mixing the template layouts, with varying MACs, seqs, signals."""
    rng = np.random.default_rng(0)
    kinds = templates()
    choice = rng.choice(len(kinds), size=n, p=[k[0] for k in kinds])
    recs = [rt + fr for _, rt, fr in kinds]
    sizes = np.array([16 + len(r) for r in recs])[choice]
    offsets = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    out = np.zeros(int(sizes.sum()), np.uint8)
    t_us = 1_700_000_000_000_000 + np.cumsum(rng.integers(50, 400, n))
    for k, rec in enumerate(recs):
        rows = offsets[choice == k]
        if len(rows) == 0:
            continue
        full = np.frombuffer(struct.pack("<IIII", 0, 0, len(rec), len(rec)) + rec, np.uint8)
        out[rows[:, None] + np.arange(len(full))] = full
        rt_len = kinds[k][1][2] | kinds[k][1][3] << 8
        if len(kinds[k][2]) > 20:  # a beacon: vary transmitter and sequence number
            ta = rows + 16 + rt_len + 10
            out[ta + 4] = rng.integers(0, 256, len(rows))
            out[ta + 5] = rng.integers(0, 64, len(rows))
            seq = rng.integers(0, 4096, len(rows)) << 4
            out[rows + 16 + rt_len + 22] = seq & 0xFF
            out[rows + 16 + rt_len + 23] = seq >> 8
    sel = t_us
    secs, usecs = sel // 1_000_000, sel % 1_000_000
    stamp = np.zeros((n, 8), np.uint8)
    stamp[:, :4] = secs.astype("<u4").view(np.uint8).reshape(n, 4)
    stamp[:, 4:] = usecs.astype("<u4").view(np.uint8).reshape(n, 4)
    out[offsets[:, None] + np.arange(8)] = stamp
    with path.open("wb") as f:
        f.write(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 127))
        f.write(out.tobytes())


def write_sized_capture(path: Path, n: int) -> None:
    """A pcap of ``n`` frames of realistic sizes: data frames of 60–1,500 bytes.

    The header layouts and their shares are those of :func:`templates`; the
    beacons become data frames (type 2) whose 802.11 frame, payload and FCS
    included, is drawn uniformly from 60 to 1,500 bytes, as on a busy
    channel. ACKs stay 14 bytes.
    """
    rng = np.random.default_rng(1)
    kinds = templates()
    choice = rng.choice(len(kinds), size=n, p=[k[0] for k in kinds])
    sizes = rng.integers(60, 1501, n)
    t_us = 1_700_000_000_000_000 + np.cumsum(rng.integers(50, 400, n))
    ta = rng.integers(0, 1 << 14, n)
    seq = rng.integers(0, 4096, n)
    payload = bytes(rng.integers(0, 256, 1400, dtype=np.uint8))
    record = struct.Struct("<IIII")
    with path.open("wb") as f:
        f.write(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 127))
        out = bytearray()
        for i in range(n):
            _, rt, frame = kinds[int(choice[i])]
            if len(frame) > 20:
                frame = (
                    struct.pack("<HH", 0x0008, 0)
                    + b"\x02" * 6
                    + b"\x02\x00\x00\x00" + int(ta[i]).to_bytes(2, "big")
                    + b"\x02" * 6
                    + struct.pack("<H", int(seq[i]) << 4)
                    + payload[: int(sizes[i]) - 28]
                    + bytes(4)
                )  # fmt: skip
            secs, usecs = divmod(int(t_us[i]), 1_000_000)
            out += record.pack(secs, usecs, len(rt) + len(frame), len(rt) + len(frame))
            out += rt + frame
            if len(out) > 1 << 22:
                f.write(out)
                out.clear()
        f.write(out)


def head(src: Path, dst: Path, n: int) -> None:
    """Copy the first ``n`` records of a little-endian pcap."""
    data = src.read_bytes()
    pos = 24
    for _ in range(n):
        if pos + 16 > len(data):
            break
        pos += 16 + struct.unpack_from("<I", data, pos + 8)[0]
    dst.write_bytes(data[:pos])


def run_ours(path: Path) -> tuple[int, int, float]:
    t0 = time.process_time()
    observations = 0
    with rfsas_hw.sources.open(f"pcap:{path}") as src:
        for batch in src:
            observations += len(batch)
        frames = src.stats.frames + sum(src.stats.skipped.values())
    return frames, observations, time.process_time() - t0


def run_parse(path: Path) -> tuple[int, float]:
    """Records found by the capture parser alone (no decoding), and CPU seconds."""
    data = path.read_bytes()
    t0 = time.process_time()
    parser = pcapfile.CaptureParser(path.name)
    parser.feed(data)
    n = 0
    while (chunk := parser.next_chunk(final=True)) is not None:
        n += len(chunk)
    return n, time.process_time() - t0


def walk_table(captures: list[tuple[str, Path]]) -> None:
    """Records per CPU second with the numpy record walk and with the record loop only."""
    walk_min = pcapfile.FAST_MIN_BYTES
    print(f"{'pcap records found':<50} {'walk /s':>12} {'loop /s':>12} {'walk is':>8}")
    for label, path in captures:
        for what, run in (("parse", run_parse), ("to observations", run_ours)):
            best: dict[str, float] = {}
            for mode in ("walk", "loop") * 3:
                pcapfile.FAST_MIN_BYTES = walk_min if mode == "walk" else 1 << 62
                got = run(path)
                rate = got[0] / got[-1]
                best[mode] = max(best.get(mode, 0.0), rate)
            pcapfile.FAST_MIN_BYTES = walk_min
            ratio = best["walk"] / best["loop"]
            print(
                f"{label + ', ' + what:<50} {best['walk']:>12,.0f} {best['loop']:>12,.0f} "
                f"{ratio:>7.2f}x"
            )


def batch_table(path: Path) -> None:
    """CPU per small batch, decoded with the gathers and with the per-frame walk."""
    chunk = pcapfile.iter_chunks(path.read_bytes(), max_frames=1 << 30)[0]
    spans = FrameSpans(
        chunk.start, chunk.caplen, chunk.t_ns, chunk.frame_no, chunk.file_offset, chunk.linktype
    )
    total = len(spans)
    print(f"{'frames per batch (default vector_min ' + str(DEFAULT_VECTOR_MIN) + ')':<50} "
          f"{'gathers µs':>12} {'walk µs':>12}")  # fmt: skip
    for n in (1, 4, 8, 16, 32, 64):
        cost = {}
        for name, vector_min in (("gathers", 0), ("walk", 1 << 30)):
            decoder = FrameDecoder(2, vector_min)
            reps = max(4000 // n, 50)
            best = float("inf")
            for _ in range(3):
                t0 = time.process_time()
                for i in range(reps):
                    k = (i * n) % (total - n)
                    decoder.decode(chunk.buf, spans.select(slice(k, k + n)))
                best = min(best, (time.process_time() - t0) / reps)
            cost[name] = best * 1e6
        print(f"{n:<50} {cost['gathers']:>12.1f} {cost['walk']:>12.1f}")


def run_tshark(path: Path) -> tuple[int, float] | None:
    exe = shutil.which("tshark")
    if exe is None:
        return None
    cmd = [exe, "-n", "-r", str(path), "-T", "fields"]
    for name in TSHARK_FIELDS:
        cmd += ["-e", name]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = subprocess.run(cmd, capture_output=True, check=True).stdout
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    return out.count(b"\n"), cpu


def run_raw(path: Path, walk: bool) -> tuple[int, float]:
    from scapy.utils import RawPcapReader

    t0 = time.process_time()
    n = 0
    with RawPcapReader(str(path)) as reader:
        for data, _meta in reader:
            if walk:
                radiotap.parse(data)
            n += 1
    return n, time.process_time() - t0


def run_scapy_full(path: Path) -> tuple[int, float]:
    from scapy.layers.dot11 import RadioTap
    from scapy.utils import PcapReader

    t0 = time.process_time()
    n = 0
    with PcapReader(str(path)) as reader:
        for pkt in reader:
            rt = pkt.getlayer(RadioTap)
            _ = (rt.dBm_AntSignal, rt.ChannelFrequency, pkt.addr2, pkt.SC)
            n += 1
    return n, time.process_time() - t0


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 500_000
    with tempfile.TemporaryDirectory() as tmp:
        full = Path(tmp) / "bench.pcap"
        write_capture(full, n)
        size_mb = full.stat().st_size / 1e6
        subsets = {}
        for name, m in (("tshark", min(n, 100_000)), ("raw", min(n, 200_000)), ("scapy", 2_000)):
            subsets[name] = Path(tmp) / f"{name}.pcap"
            head(full, subsets[name], m)

        rows: list[tuple[str, int, float | None, str]] = []
        run_ours(subsets["scapy"])  # warm-up: imports and first-use tables, not reading
        frames, obs, t = min((run_ours(full) for _ in range(2)), key=lambda r: r[2])
        ours = frames / t
        rows.append(("rfsas-hw pcap: source (per-chain observations)", frames, t, ""))
        got = run_tshark(subsets["tshark"])
        if got is None:
            rows.append(("tshark -T fields (same fields)", 0, None, "tshark is NOT installed"))
        else:
            rows.append(("tshark -T fields (same fields)", got[0], got[1], ""))
        k, t = run_raw(subsets["raw"], walk=False)
        rows.append(("scapy RawPcapReader (records only)", k, t, "no radiotap decoding"))
        k, t = run_raw(subsets["raw"], walk=True)
        rows.append(("RawPcapReader + rfsas-hw per-frame walk", k, t, ""))
        k, t = run_scapy_full(subsets["scapy"])
        rows.append(("scapy full dissection (PcapReader)", k, t, "no per-chain fields"))

    print(f"capture: {n:,} frames, {size_mb:.1f} MB; {obs:,} observations out of {frames:,}")
    print(f"{'reader':<50} {'frames':>9} {'frames/s':>12} {'ours is':>9}  note")
    tshark_rate = None
    for name, count, secs, note in rows:
        if secs is None:
            print(f"{name:<50} {'-':>9} {'-':>12} {'-':>9}  {note}")
            continue
        rate = count / secs
        if name.startswith("tshark"):
            tshark_rate = rate
        ratio = "1.0x" if rate == ours else f"{ours / rate:,.1f}x"
        print(f"{name:<50} {count:>9,} {rate:>12,.0f} {ratio:>9}  {note}")
    print()
    verdict = "met" if ours >= GOAL_PER_S else "NOT met"
    print(f"goal {GOAL_PER_S:,} frames/s on one core: {verdict} ({ours:,.0f})")
    if tshark_rate is None:
        print("goal 30x tshark: not measured - tshark is not installed (apt-get install tshark)")
    else:
        verdict = "met" if ours / tshark_rate >= GOAL_VS_TSHARK else "NOT met"
        print(f"goal {GOAL_VS_TSHARK:.0f}x tshark: {verdict} ({ours / tshark_rate:,.1f}x)")
    print()
    with tempfile.TemporaryDirectory() as tmp:
        small, sized = Path(tmp) / "small.pcap", Path(tmp) / "sized.pcap"
        write_capture(small, n)
        write_sized_capture(sized, max(n // 4, 1))
        run_ours(sized)  # warm-up: first use of the larger frames
        walk_table([("small frames", small), ("60-1,500 B data frames", sized)])
        print()
        batch_table(small)


if __name__ == "__main__":
    main()
