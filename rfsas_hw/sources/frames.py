"""Captured frames (radiotap or bare 802.11) to columns, many frames per numpy call.

A capture reader (file, pipe or socket) hands over one buffer and, per frame,
where the frame starts, how many bytes were captured and when. The
:class:`FrameDecoder` turns that into a :class:`FrameTable`:

1. Frames are grouped by their sequence of radiotap present words. Each group
   has fixed field offsets (see :func:`~rfsas_hw.sources.radiotap.compile_layout`),
   so every field is one numpy gather for the whole group.
2. Frames whose header is unusual (vendor data before the chains, more than
   ``MAX_FAST_WORDS`` present words, a header too short for its layout) and
   every malformed frame go through the per-frame walk, which is also the one
   place that words the error for a bad frame.

Small batches (live capture) skip the grouping: numpy's per-call cost is
larger than the per-frame walk below ``vector_min`` frames. The field offsets
of the gathers come from the walk itself (``compile_layout``), so there is one
radiotap decoder.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import CaptureFormatError
from rfsas_hw.records import NO_SEQ, ObservationBatch, ObsFlag
from rfsas_hw.rf.channels import freq_to_channel
from rfsas_hw.sources import dot11, radiotap
from rfsas_hw.sources.pcapfile import FrameProblem

LINKTYPE_IEEE802_11 = 105
"""Bare 802.11 frames, no per-frame radio information."""
LINKTYPE_RADIOTAP = 127
"""802.11 frames behind a radiotap header."""

MAX_FAST_WORDS = 8
"""Headers with more present words than this are walked one by one."""
DEFAULT_VECTOR_MIN = 16
"""Below this many frames a batch is decoded frame by frame (by the walk).

Where a batch of two-chain frames costs the same either way, measured with
``bench/bench_capture.py``'s layouts."""
SENTINEL_DBM = (-128, 0)
"""Chain values drivers use for "no measurement" (iwlwifi S8_MIN; 0 in some vectors)."""

# Skip reasons (the keys of SourceStats.skipped).
R_RADIOTAP = "malformed radiotap header"
R_DOT11 = "malformed 802.11 header"
R_BAD_FCS = "bad FCS"
R_NO_TA = "no transmitter address (ACK/CTS)"
R_LINKTYPE = "unsupported link type"
# Counters of frames kept but flagged (SourceStats.extra["flagged"]).
F_NO_CHAINS = "no per-antenna signal"
F_SENTINEL = "sentinel chain value"
F_NO_SIGNAL = "no signal at all"
F_EXTRA_CHAIN = "chain index beyond n_antennas"


@dataclass(slots=True)
class FrameTable:
    """Decoded frames, one row each. Holds raw MACs: sensor-internal only."""

    frame_no: npt.NDArray[np.int64]
    """Frame number in the capture, 1-based (as Wireshark counts)."""
    t_ns: npt.NDArray[np.int64]
    """Capture time, UTC nanoseconds."""
    tsft_us: npt.NDArray[np.uint64]
    """Radiotap TSFT (receiver MAC clock), µs; valid where ``has_tsft``."""
    has_tsft: npt.NDArray[np.bool_]
    """True where the header carried TSFT."""
    rt_flags: npt.NDArray[np.uint8]
    """Radiotap Flags byte (0 when absent)."""
    freq_mhz: npt.NDArray[np.int32]
    """Channel frequency, MHz (0 when absent)."""
    signal_dbm: npt.NDArray[np.float32]
    """Combined signal (namespace 0), dBm; NaN when absent."""
    chain_dbm: npt.NDArray[np.float32]
    """Per-chain signal by antenna index, dBm, shape (n, width); NaN when absent; sentinels kept."""
    ftype: npt.NDArray[np.uint8]
    """802.11 frame type."""
    subtype: npt.NDArray[np.uint8]
    """802.11 frame subtype."""
    retry: npt.NDArray[np.bool_]
    """802.11 retry bit."""
    mac: npt.NDArray[np.uint64]
    """Transmitter address as a 48-bit int."""
    seq: npt.NDArray[np.int32]
    """Sequence number, or ``NO_SEQ``."""
    frag: npt.NDArray[np.int16]
    """Fragment number, or -1."""

    @classmethod
    def allocate(cls, n: int, width: int) -> FrameTable:
        """A table of ``n`` rows with neutral values (NaN signals, no TSFT)."""
        signal = np.empty(n, np.float32)
        signal.fill(np.nan)
        chains = np.empty((n, width), np.float32)
        chains.fill(np.nan)
        seq = np.empty(n, np.int32)
        seq.fill(NO_SEQ)
        frag = np.empty(n, np.int16)
        frag.fill(-1)
        return cls(
            frame_no=np.zeros(n, np.int64),
            t_ns=np.zeros(n, np.int64),
            tsft_us=np.zeros(n, np.uint64),
            has_tsft=np.zeros(n, bool),
            rt_flags=np.zeros(n, np.uint8),
            freq_mhz=np.zeros(n, np.int32),
            signal_dbm=signal,
            chain_dbm=chains,
            ftype=np.zeros(n, np.uint8),
            subtype=np.zeros(n, np.uint8),
            retry=np.zeros(n, bool),
            mac=np.zeros(n, np.uint64),
            seq=seq,
            frag=frag,
        )

    def __len__(self) -> int:
        return int(self.frame_no.shape[0])

    @property
    def width(self) -> int:
        """Number of per-chain columns."""
        return int(self.chain_dbm.shape[1])

    def select(self, index: npt.NDArray[Any] | slice) -> FrameTable:
        """Rows picked by a mask, an index array or a slice."""
        return FrameTable(**{f.name: _rows(getattr(self, f.name), index) for f in fields(self)})

    @staticmethod
    def concat(tables: list[FrameTable], width: int) -> FrameTable:
        """Concatenate tables (all of ``width`` chain columns)."""
        if not tables:
            return FrameTable.allocate(0, width)
        return FrameTable(
            **{
                f.name: np.concatenate([getattr(t, f.name) for t in tables])
                for f in fields(FrameTable)
            }
        )

    def to_observations(self, flagged: Counter[str] | None = None) -> ObservationBatch:
        """Observations with sentinel chains replaced by NaN and quality flags set.

        ``flagged`` (if given) counts frames kept with a flag: no per-antenna
        signal, sentinel chain values, no signal at all.
        """
        chains = self.chain_dbm
        sentinel = chains == np.float32(SENTINEL_DBM[0])
        for value in SENTINEL_DBM[1:]:
            sentinel |= chains == np.float32(value)
        rssi = np.where(sentinel, np.float32(np.nan), chains)
        any_sentinel = _rows_any(sentinel)
        no_chains = _rows_all(np.isnan(chains))
        no_signal = no_chains & np.isnan(self.signal_dbm)
        flags = self.retry * np.uint16(ObsFlag.RETRY)
        flags |= any_sentinel * np.uint16(ObsFlag.SENTINEL_CHAIN)
        flags |= _rows_any(np.isnan(rssi)) * np.uint16(ObsFlag.MISSING_CHAIN)
        flags |= no_signal * np.uint16(ObsFlag.NO_SIGNAL)
        if flagged is not None:
            for key, mask in (
                (F_NO_CHAINS, no_chains),
                (F_SENTINEL, any_sentinel),
                (F_NO_SIGNAL, no_signal),
            ):
                count = int(mask.sum())
                if count:
                    flagged[key] += count
        return ObservationBatch(
            t_ns=self.t_ns,
            mac=self.mac,
            freq_mhz=self.freq_mhz,
            channel=freq_to_channel(self.freq_mhz),
            rssi_dbm=rssi,
            seq=self.seq,
            kind=dot11.kind_of(self.ftype, self.subtype),
            flags=flags,
        )


@dataclass(slots=True)
class FrameSpans:
    """Where each captured frame lies in a buffer, and when it was captured."""

    start: npt.NDArray[np.int64]
    """Offset of the frame's first byte in the buffer."""
    caplen: npt.NDArray[np.int64]
    """Captured bytes of the frame."""
    t_ns: npt.NDArray[np.int64]
    """Capture time, UTC nanoseconds."""
    frame_no: npt.NDArray[np.int64]
    """Frame number in the capture, 1-based."""
    file_offset: npt.NDArray[np.int64]
    """Byte offset of the frame's record in the file or stream (for messages)."""
    linktype: npt.NDArray[np.int32]
    """Link-layer type of each frame."""

    def __len__(self) -> int:
        return int(self.start.shape[0])

    def select(self, index: npt.NDArray[Any] | slice) -> FrameSpans:
        """Rows picked by a mask, an index array or a slice."""
        return FrameSpans(**{f.name: getattr(self, f.name)[index] for f in fields(self)})


@dataclass(slots=True)
class DecodeResult:
    """What one decode call produced."""

    table: FrameTable
    """Frames kept, in capture order."""
    problems: list[FrameProblem] = field(default_factory=list)
    """Malformed frames (each lost), with frame number and byte offset."""
    dropped: Counter[str] = field(default_factory=Counter)
    """Well-formed frames dropped on purpose (bad FCS, no transmitter), by reason."""
    flagged: Counter[str] = field(default_factory=Counter)
    """Notes on frames kept (chains beyond the table width)."""


def _view(buf: bytes, dtype: str, size: int) -> npt.NDArray[Any]:
    """Every byte offset of ``buf`` as the start of a ``dtype`` value (unaligned, read-only)."""
    n = max(len(buf) - size + 1, 0)
    return np.ndarray((n,), dtype=dtype, buffer=buf, offset=0, strides=(1,))


class _Views:
    __slots__ = ("i8", "u8", "u16", "u16be", "u32", "u32be", "u64", "u64be")

    def __init__(self, buf: bytes) -> None:
        self.u8 = np.frombuffer(buf, np.uint8)
        self.i8 = np.frombuffer(buf, np.int8)
        self.u16 = _view(buf, "<u2", 2)
        self.u16be = _view(buf, ">u2", 2)
        self.u32 = _view(buf, "<u4", 4)
        self.u32be = _view(buf, ">u4", 4)
        self.u64 = _view(buf, "<u8", 8)
        self.u64be = _view(buf, ">u8", 8)


class FrameDecoder:
    """Decode captured 802.11 frames (radiotap or bare) into a :class:`FrameTable`.

    Args:
        n_antennas: per-chain columns kept (chain index ``k`` goes to column ``k``).
        vector_min: batches smaller than this are decoded frame by frame.
    """

    def __init__(self, n_antennas: int = 2, vector_min: int = DEFAULT_VECTOR_MIN) -> None:
        if n_antennas < 1:
            raise ValueError(f"n_antennas must be at least 1, got {n_antennas}")
        self.width = n_antennas
        self.vector_min = vector_min
        self._empty = FrameTable.allocate(0, n_antennas)
        # (present words, vendor skip length or -1) -> layout
        self._layouts: dict[tuple[tuple[int, ...], int], radiotap.Layout] = {}
        # present words -> the first layout compiled for them
        self._first: dict[tuple[int, ...], radiotap.Layout] = {}

    # -- entry point --------------------------------------------------------------

    def decode(self, buf: bytes, spans: FrameSpans) -> DecodeResult:
        """Decode every frame in ``spans`` (offsets into ``buf``)."""
        result = DecodeResult(self._empty)
        if len(spans) == 0:
            return result
        # Reads are bounds-checked against their frame; rows found bad read offset 0
        # instead, which a tiny buffer might not have.
        padded = buf if len(buf) >= 64 else bytes(buf) + bytes(64)
        tables: list[FrameTable] = []
        first = int(spans.linktype[0])
        single = bool((spans.linktype == first).all())
        for lt in [first] if single else np.unique(spans.linktype).tolist():
            part = spans if single else spans.select(spans.linktype == lt)
            if lt in (LINKTYPE_RADIOTAP, LINKTYPE_IEEE802_11):
                tables.append(self._decode_group(padded, part, lt == LINKTYPE_RADIOTAP, result))
            else:
                result.dropped[f"{R_LINKTYPE} {lt}"] += len(part)
        if len(tables) == 1:
            result.table = tables[0]
        elif tables:
            # Several link types (pcapng interfaces): back into capture order.
            merged = FrameTable.concat(tables, self.width)
            result.table = merged.select(np.argsort(merged.frame_no, kind="stable"))
        result.problems.sort(key=lambda p: p.frame_no)
        return result

    # -- one link type -------------------------------------------------------------

    def _decode_group(
        self, buf: bytes, spans: FrameSpans, is_radiotap: bool, result: DecodeResult
    ) -> FrameTable:
        n = len(spans)
        table = FrameTable.allocate(n, self.width)
        table.frame_no[:] = spans.frame_no
        table.t_ns[:] = spans.t_ns
        keep = np.ones(n, bool)
        if n >= self.vector_min:
            slow = self._fast(buf, spans, is_radiotap, table, keep, result)
        else:
            slow = np.arange(n)
        for i in slow.tolist():
            self._slow_row(buf, spans, i, is_radiotap, table, keep, result)
        return table.select(keep) if not keep.all() else table

    def _slow_row(
        self,
        buf: bytes,
        spans: FrameSpans,
        i: int,
        is_radiotap: bool,
        table: FrameTable,
        keep: npt.NDArray[np.bool_],
        result: DecodeResult,
    ) -> None:
        start = int(spans.start[i])
        avail = int(spans.caplen[i])
        rt_len = 0
        fcs = False
        reason = R_RADIOTAP
        try:
            if is_radiotap:
                info = radiotap.parse_at(buf, start, avail)
                rt_len = info.length
                flags = info.flags or 0
                fcs = bool(flags & radiotap.FLAG_FCS_AT_END)
                if info.tsft_us is not None:
                    table.tsft_us[i] = info.tsft_us
                    table.has_tsft[i] = True
                table.rt_flags[i] = flags
                table.freq_mhz[i] = info.channel_mhz or 0
                if info.signal_dbm is not None:
                    table.signal_dbm[i] = info.signal_dbm
                for ant, dbm in info.chains:
                    if ant < self.width:
                        table.chain_dbm[i, ant] = dbm
                    else:
                        result.flagged[F_EXTRA_CHAIN] += 1
            reason = R_DOT11
            flen = avail - rt_len - (dot11.FCS_LEN if fcs else 0)
            if flen < 0:
                raise CaptureFormatError(
                    f"802.11: radiotap announces an FCS but only {avail - rt_len} bytes follow"
                )
            hdr = dot11.parse_header(buf, start + rt_len, flen)
        except CaptureFormatError as err:
            keep[i] = False
            result.problems.append(
                FrameProblem(reason, int(spans.frame_no[i]), int(spans.file_offset[i]), str(err))
            )
            return
        if table.rt_flags[i] & radiotap.FLAG_BAD_FCS:
            keep[i] = False
            result.dropped[R_BAD_FCS] += 1
            return
        if hdr.transmitter is None:
            keep[i] = False
            result.dropped[R_NO_TA] += 1
            return
        table.ftype[i] = hdr.type
        table.subtype[i] = hdr.subtype
        table.retry[i] = hdr.retry
        table.mac[i] = hdr.transmitter
        if hdr.seq is not None:
            table.seq[i] = hdr.seq
            table.frag[i] = hdr.frag if hdr.frag is not None else -1

    # -- vectorised path -----------------------------------------------------------

    def _fast(
        self,
        buf: bytes,
        spans: FrameSpans,
        is_radiotap: bool,
        table: FrameTable,
        keep: npt.NDArray[np.bool_],
        result: DecodeResult,
    ) -> npt.NDArray[np.int64]:
        """Decode what can be decoded with gathers; return the rows left for the walk."""
        v = _Views(buf)
        h = spans.start
        avail = spans.caplen
        n = len(h)
        slow = np.zeros(n, bool)
        if is_radiotap:
            rt_len, fcs = self._fast_radiotap(buf, v, h, avail, table, slow, result)
        else:
            rt_len = np.zeros(n, np.int64)
            fcs = np.zeros(n, bool)
        # 802.11 header, for rows whose radiotap part went through.
        s = h + rt_len
        flen = avail - rt_len - np.where(fcs, dot11.FCS_LEN, 0)
        slow |= flen < dot11.MIN_FRAME_LEN
        s_safe = np.where(slow, 0, s)
        fc = v.u16[s_safe]
        ftype = (fc >> 2) & 3
        subtype = (fc >> 4) & 0xF
        slow |= (fc & 3) != 0
        slow |= flen < dot11.required_length_batch(ftype, subtype)
        ok = ~slow
        bad_fcs = ok & ((table.rt_flags & radiotap.FLAG_BAD_FCS) != 0)
        has_ta = dot11.has_transmitter_batch(ftype, subtype)
        no_ta = ok & ~bad_fcs & ~has_ta
        for reason, mask in ((R_BAD_FCS, bad_fcs), (R_NO_TA, no_ta)):
            count = int(mask.sum())
            if count:
                result.dropped[reason] += count
        keep &= ~(bad_fcs | no_ta)
        good = ok & ~bad_fcs & has_ta
        # Whole-column writes: rows that are not good are either dropped or decoded
        # again by the walk, which overwrites these columns.
        table.ftype[:] = ftype
        table.subtype[:] = subtype
        table.retry[:] = (fc & dot11.FC_RETRY) != 0
        # addr2 is the low 48 bits of the big-endian 8 bytes from offset 8.
        table.mac[:] = v.u64be[np.where(good, s_safe, 0) + 8] & np.uint64(0xFFFF_FFFF_FFFF)
        with_seq = good & ((ftype == dot11.TYPE_MGMT) | (ftype == dot11.TYPE_DATA))
        sc = v.u16[np.where(with_seq, s_safe, 0) + 22]
        table.seq[:] = np.where(with_seq, (sc >> 4).astype(np.int32), np.int32(NO_SEQ))
        table.frag[:] = np.where(with_seq, (sc & 0xF).astype(np.int16), np.int16(-1))
        return np.flatnonzero(slow)

    def _fast_radiotap(
        self,
        buf: bytes,
        v: _Views,
        h: npt.NDArray[np.int64],
        avail: npt.NDArray[np.int64],
        table: FrameTable,
        slow: npt.NDArray[np.bool_],
        result: DecodeResult,
    ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
        n = len(h)
        slow |= avail < radiotap.MIN_HEADER_LEN
        hs = np.where(slow, 0, h)
        # Version, pad, it_len and the first present word: one 8-byte read.
        head = v.u64[hs]
        it_len = ((head >> np.uint64(16)) & np.uint64(0xFFFF)).astype(np.int64)
        version = head & np.uint64(0xFF)
        slow |= (version != 0) | (it_len < radiotap.MIN_HEADER_LEN) | (it_len > avail)
        # Present words, one array per position, zero after a header's last word.
        limit = len(buf) - 4
        words: list[npt.NDArray[np.uint32]] = [(head >> np.uint64(32)).astype(np.uint32)]
        more = ~slow & ((words[0] >> 31) != 0)
        while more.any():
            k = len(words)
            if k == MAX_FAST_WORDS:
                slow |= more
                break
            slow |= more & (it_len < 8 + 4 * (k + 1))
            more &= ~slow
            word = np.where(more, v.u32[np.minimum(hs + 4 + 4 * k, limit)], np.uint32(0))
            words.append(word)
            more &= (word >> 31) != 0
        live = np.flatnonzero(~slow)
        if len(live) == 0:
            return np.zeros(n, np.int64), np.zeros(n, bool)
        if len(words) & 1:
            words.append(np.zeros(n, np.uint32))
        # Exact group keys: pairs of present words as 64-bit integers.
        columns = [
            words[j][live].astype(np.uint64)
            | (words[j + 1][live].astype(np.uint64) << np.uint64(32))
            for j in range(0, len(words), 2)
        ]
        nwords = len(words)
        for members in _groups(columns):
            rows = live[members]
            present = _trim(tuple(int(words[j][rows[0]]) for j in range(nwords)))
            first = self._layout(buf, present, -1, int(h[rows[0]]), int(avail[rows[0]]))
            if first is None or not first.vectorisable:
                slow[rows] = True
                continue
            if first.vendor_skip_at < 0:
                parts = [(rows, first)]
            else:
                # Frames with the same words but other vendor data lengths: one layout each.
                readable = it_len[rows] >= first.vendor_skip_at + 2
                slow[rows[~readable]] = True
                rows = rows[readable]
                skips = v.u16[h[rows] + first.vendor_skip_at]
                parts = []
                for skip in np.unique(skips).tolist():
                    sub = rows[skips == skip]
                    got = self._layout(buf, present, skip, int(h[sub[0]]), int(avail[sub[0]]))
                    if got is None:
                        slow[sub] = True
                    else:
                        parts.append((sub, got))
            for sub, layout in parts:
                short = it_len[sub] < layout.min_len
                if short.any():
                    slow[sub[short]] = True
                    sub = sub[~short]
                self._gather(v, h[sub], sub, layout, table, result)
        return np.where(slow, 0, it_len), (table.rt_flags & radiotap.FLAG_FCS_AT_END) != 0

    def _layout(
        self, buf: bytes, present: tuple[int, ...], skip: int, start: int, avail: int
    ) -> radiotap.Layout | None:
        """The layout for these present words (and vendor skip length, -1 for any),
        compiled from the frame at ``start`` if not cached; None if that frame is malformed."""
        if skip < 0:
            first = self._first.get(present)
            if first is not None:
                return first
        else:
            got = self._layouts.get((present, skip))
            if got is not None:
                return got
        try:
            layout = radiotap.compile_layout(buf, start, avail)
        except CaptureFormatError:
            # This frame is malformed; another frame with the same words may not be.
            return None
        if len(self._layouts) > 4096:
            self._layouts.clear()
            self._first.clear()
        self._first.setdefault(present, layout)
        self._layouts[(present, layout.vendor_skip)] = layout
        if skip >= 0 and layout.vendor_skip != skip:
            return None
        return layout

    def _gather(
        self,
        v: _Views,
        hr: npt.NDArray[np.int64],
        rows: npt.NDArray[np.int64],
        layout: radiotap.Layout,
        table: FrameTable,
        result: DecodeResult,
    ) -> None:
        if len(rows) == 0:
            return
        if layout.tsft >= 0:
            table.tsft_us[rows] = v.u64[hr + layout.tsft]
            table.has_tsft[rows] = True
        if layout.flags >= 0:
            table.rt_flags[rows] = v.u8[hr + layout.flags]
        if layout.channel >= 0:
            table.freq_mhz[rows] = v.u16[hr + layout.channel]
        if layout.signal >= 0:
            table.signal_dbm[rows] = v.i8[hr + layout.signal]
        for ant_off, sig_off in layout.chains:
            ant = v.u8[hr + ant_off]
            sig = v.i8[hr + sig_off]
            inside = ant < self.width
            if (ant == ant[0]).all() and inside[0]:
                table.chain_dbm[rows, int(ant[0])] = sig
            elif inside.all():
                table.chain_dbm[rows, ant] = sig
            else:
                table.chain_dbm[rows[inside], ant[inside]] = sig[inside]
                result.flagged[F_EXTRA_CHAIN] += int((~inside).sum())


def _groups(columns: list[npt.NDArray[np.uint64]]) -> list[npt.NDArray[np.int64]]:
    """Row indexes grouped by equal key (one value per column), each group in row order.

    Captures hold a handful of layouts, so peeling off one key at a time
    (whole-column comparisons, no gathers) beats sorting; many layouts fall
    back to a sort.
    """
    groups: list[npt.NDArray[np.int64]] = []
    remaining = np.ones(len(columns[0]), bool)
    first = 0
    while len(groups) < 8:
        same = columns[0] == columns[0][first]
        for col in columns[1:]:
            same &= col == col[first]
        same &= remaining
        groups.append(np.flatnonzero(same))
        remaining &= ~same
        left = int(remaining.argmax())
        if not remaining[left]:
            return groups
        first = left
    rest = np.flatnonzero(remaining)
    key = np.stack([col[rest] for col in columns], axis=1)
    _, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    order = np.argsort(inverse, kind="stable")
    bounds = np.flatnonzero(np.diff(inverse[order])) + 1
    groups.extend(rest[part] for part in np.split(order, bounds))
    return groups


def _rows(column: npt.NDArray[Any], index: npt.NDArray[Any] | slice) -> npt.NDArray[Any]:
    """``column[index]``; a 2-D column's rows are picked as single opaque items.

    numpy picks rows of a narrow 2-D array by a mask about ten times slower
    than items of a 1-D array of the same bytes.
    """
    if column.ndim != 2 or isinstance(index, slice) or column.shape[1] * column.itemsize == 0:
        return column[index]
    whole = np.ascontiguousarray(column)
    rows = whole.view(np.dtype((np.void, whole.shape[1] * whole.itemsize))).ravel()
    picked: npt.NDArray[Any] = rows[index].view(column.dtype).reshape(-1, column.shape[1])
    return picked


def _rows_any(mask: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """Per row: any column true (a column loop: numpy's ``any(axis=1)`` is slow on few columns)."""
    out = np.zeros(mask.shape[0], bool)
    for k in range(mask.shape[1]):
        out |= mask[:, k]
    return out


def _rows_all(mask: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """Per row: every column true (see :func:`_rows_any`)."""
    out = np.ones(mask.shape[0], bool)
    for k in range(mask.shape[1]):
        out &= mask[:, k]
    return out


def _trim(words: tuple[int, ...]) -> tuple[int, ...]:
    """Cut the zero padding after the last present word (the first without bit 31)."""
    for i, word in enumerate(words):
        if not word >> 31:
            return words[: i + 1]
    return words
