"""Atheros CSI Tool ``.dat``, PicoScenes ``.csi`` and nexmon_csi pcaps, parsed with ``csiread``.

``csiread`` (MIT, the ``csi`` extra) is imported on first use. What it
returns is checked and reshaped into :class:`~rfsas_hw.sources.csi_frames.CsiFrames`;
where it fails on a file, the error names the file and the reason.

* Atheros: per-chain RSSI in the tool's dB scale (above its noise floor),
  no transmitter address in the record (0); time is the card's TSF in µs.
* PicoScenes: per-chain RSSI in dBm with −128 for a chain that is absent
  (flagged ``SENTINEL_CHAIN``); transmitter address, sequence number, centre
  frequency and TSF time from the frame. ``csiread`` needs the largest CSI
  shape up front and fails (IndexError) when it is too small, so sizes are
  tried from small to large.
* nexmon_csi: one UDP packet per core × spatial stream; consecutive packets
  with the same transmitter and sequence number and a new (core, stream)
  are one frame (core → antenna, stream → stream). Channel and bandwidth
  come from the chanspec; the new format (2-byte magic) carries RSSI, the
  old one does not (flagged ``NO_SIGNAL``).
"""

from __future__ import annotations

import contextlib
import sys
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import CaptureFormatError, RfsasError
from rfsas_hw.optional import require
from rfsas_hw.records import ObsFlag
from rfsas_hw.sources.csi_frames import CsiCapture, new_frames, ofdm_subcarriers

PICO_SENTINEL_DBM = -128
PICO_SIZES = (64, 128, 256, 512, 1024, 2048)
"""CSI tone counts tried in turn for PicoScenes (20 MHz … 160 MHz HE)."""
NEXMON_CHIPS = {0x65: "43455c0", 0x6A: "4366c0", 0x24: "4339", 0x38: "4358"}
"""nexmon chip_version field → chip name ``csiread`` understands (values from the samples)."""


def _csiread() -> Any:
    return require("csiread")


def _fail(path: str, what: str, err: Exception) -> CaptureFormatError:
    return CaptureFormatError(
        f"{path}: csiread cannot read this {what} file: {type(err).__name__}: {err}"
    )


def _macs(rows: npt.NDArray[Any]) -> npt.NDArray[np.uint64]:
    """(n, 6) address bytes → 48-bit ints."""
    b = np.asarray(rows, dtype=np.uint64).reshape(-1, 6)
    out = np.zeros(len(b), np.uint64)
    for k in range(6):
        out = (out << np.uint64(8)) | b[:, k]
    return out


def read_atheros(path: str | Path, freq_mhz: int = 0) -> CsiCapture:
    """Every frame of an Atheros CSI Tool file (byte order detected).

    Raises:
        CaptureFormatError: csiread fails, or finds no plausible frame in either byte order.
        MissingDependencyError: csiread is not installed.
    """
    name = str(path)
    lib = _csiread()
    best = None
    for endian in ("little", "big"):
        for tones in (56, 114):
            try:
                d = lib.Atheros(name, nrxnum=3, ntxnum=3, tones=tones, if_report=False)
                d.read(endian=endian)
            except Exception as err:  # csiread raises bare built-ins on foreign files
                raise _fail(name, "Atheros", err) from err
            n = int(d.count)
            ok = (
                n > 0
                and np.all((d.nr[:n] >= 1) & (d.nr[:n] <= 3))
                and np.all(d.num_tones[:n] == tones)
            )
            if ok:
                best = (d, n, tones)
                break
        if best is not None:
            break
    if best is None:
        raise CaptureFormatError(
            f"{name}: no Atheros CSI frame with 1–3 RX chains and 56 or 114 tones in either "
            "byte order: not an Atheros CSI Tool file"
        )
    d, n, tones = best
    nrx, ntx = int(d.nr[:n].max()), int(d.nc[:n].max())
    frames = new_frames("atheros", n, nrx, ntx, ofdm_subcarriers(tones))
    csi = np.asarray(d.csi[:n], np.complex64)  # (n, sc, rx, tx)
    frames.h[:] = csi[:, :, :nrx, :ntx].transpose(0, 2, 3, 1)
    for k in range(nrx):
        frames.h[d.nr[:n] <= k, k] = np.nan
    rssi = np.stack([d.rssi_1[:n], d.rssi_2[:n], d.rssi_3[:n]], axis=1)[:, :nrx]
    frames.rssi_dbm[:] = rssi.astype(np.float32) + d.noise_floor[:n, None].astype(np.float32)
    frames.t_ns[:] = d.timestamp[:n].astype(np.int64) * 1000
    chan = np.asarray(d.tx_channel[:n], np.int32)
    frames.freq_mhz[:] = np.where(chan > 0, chan, freq_mhz)
    bad = np.asarray(d.err_info[:n]) != 0
    notes: Counter[str] = Counter()
    notes["phy errors"] = int(bad.sum())
    return CsiCapture(name, "atheros", [frames], "dB (Atheros scale)", [], notes)


def _pico_read(lib: Any, name: str) -> Any:
    last: Exception | None = None
    for size in PICO_SIZES:
        try:
            d = lib.Picoscenes(name, {"CSI": [size, 4, 4]}, if_report=False)
            d.read()
        except IndexError as err:  # the CSI did not fit: try larger
            last = err
            continue
        except Exception as err:
            raise _fail(name, "PicoScenes", err) from err
        info = d.raw["CSI"]["Info"]
        if int(d.count) and int(info["NumTones"].max()) <= size:
            return d
    raise CaptureFormatError(
        f"{name}: csiread cannot read this PicoScenes file with CSI up to {PICO_SIZES[-1]} "
        f"tones × 4 × 4: {type(last).__name__ if last else 'no frame'}: {last}"
    )


def read_picoscenes(path: str | Path, freq_mhz: int = 0) -> CsiCapture:
    """Every frame of a PicoScenes ``.csi`` file (one block; the union of tone sets).

    Raises:
        CaptureFormatError: csiread fails at every CSI size, or the file has no frame.
        MissingDependencyError: csiread is not installed.
    """
    name = str(path)
    d = _pico_read(_csiread(), name)
    raw = d.raw[: int(d.count)]
    info = raw["CSI"]["Info"]
    basic = raw["RxSBasic"]
    nsc = info["NumTones"].astype(int)
    nrx_all = info["NumRx"].astype(int)
    ntx_all = (info["NumTx"] + info["NumESS"]).astype(int)
    notes: Counter[str] = Counter()
    has = (nsc > 0) & (nrx_all > 0) & (ntx_all > 0)
    notes["frames without CSI"] = int((~has).sum())
    idx = np.flatnonzero(has)
    if len(idx) == 0:
        raise CaptureFormatError(f"{name}: PicoScenes file holds no frame with CSI")
    # frames may alternate between tone sets (e.g. 52 legacy / 56 HT): one column per
    # subcarrier index seen, NaN where a frame has none
    sub_rows = raw["CSI"]["SubcarrierIndex"]
    # csiread pads the index list with its last value; some frames (AX200 HT) report
    # more tones than they carry: keep the strictly increasing prefix
    for i in idx:
        steps = np.diff(sub_rows[i][: nsc[i]].astype(int))
        stop = np.flatnonzero(steps <= 0)
        if len(stop):
            notes["frames reporting more tones than they carry"] += 1
            nsc[i] = int(stop[0]) + 1
    union = np.unique(np.concatenate([sub_rows[i][: nsc[i]] for i in idx])).astype(np.int16)
    nrx, ntx = int(nrx_all[idx].max()), int(ntx_all[idx].max())
    frames = new_frames("picoscenes", len(idx), nrx, ntx, union)
    csi_all = raw["CSI"]["CSI"]
    for row, i in enumerate(idx):
        cols = np.searchsorted(union, sub_rows[i][: nsc[i]])
        block = np.asarray(csi_all[i][: nsc[i], : nrx_all[i], : ntx_all[i]], np.complex64)
        frames.h[row, : nrx_all[i], : ntx_all[i]][:, :, cols] = block.transpose(1, 2, 0)
    rssi_raw = np.stack([basic["RSSI1"], basic["RSSI2"], basic["RSSI3"]], axis=1)[idx]
    rssi = rssi_raw[:, :nrx].astype(np.float32)
    sentinel = rssi <= PICO_SENTINEL_DBM
    rssi[sentinel] = np.nan
    frames.rssi_dbm[:] = rssi
    frames.flags[np.any(sentinel, axis=1)] |= np.uint16(ObsFlag.SENTINEL_CHAIN)
    notes["absent chains (RSSI −128) beyond NumRx"] = int(
        np.sum(rssi_raw[:, nrx:] <= PICO_SENTINEL_DBM)
    )
    t_us = basic["Timestamp"][idx].astype(np.int64)
    blank = t_us == 0
    if blank.any():
        # frames without a time take the previous frame's (csiread leaves 0)
        notes["frames without a timestamp"] = int(blank.sum())
        last = np.maximum.accumulate(np.where(blank, 0, np.arange(len(t_us))))
        t_us = t_us[last]
    frames.t_ns[:] = t_us * 1000
    frames.mac[:] = _macs(raw["StandardHeader"]["Addr2"][idx])
    frames.seq[:] = raw["StandardHeader"]["Sequence"][idx].astype(np.int32) & 0xFFF
    centre = basic["CenterFreq"][idx].astype(np.int32)
    frames.freq_mhz[:] = np.where(centre > 0, centre, freq_mhz)
    blocks = [frames]
    return CsiCapture(name, "picoscenes", blocks, "dBm", [], notes)


def _nexmon_header(name: str) -> tuple[int, int, bool]:
    """(chip_version, chanspec, new_format) of the first nexmon packet, read from the pcap.

    Raises:
        CaptureFormatError: not a pcap, or no UDP packet with a nexmon magic.
    """
    raw = Path(name).read_bytes()[: 1 << 16]
    if len(raw) < 24 or raw[:4] not in (b"\xd4\xc3\xb2\xa1", b"\x4d\x3c\xb2\xa1"):
        raise CaptureFormatError(f"{name}: not a little-endian pcap file (nexmon_csi writes pcap)")
    pos = 24
    while pos + 16 <= len(raw):
        caplen = int.from_bytes(raw[pos + 8 : pos + 12], "little")
        pkt = raw[pos + 16 : pos + 16 + caplen]
        pos += 16 + caplen
        # Ethernet (14) + IPv4 (20) + UDP (8)
        if len(pkt) < 60 or pkt[12:14] != b"\x08\x00" or pkt[23] != 17:
            continue
        body = pkt[42:]
        if body[:4] == b"\x11\x11\x11\x11":
            return (
                int.from_bytes(body[16:18], "little"),
                int.from_bytes(body[14:16], "little"),
                False,
            )
        if body[:2] == b"\x11\x11":
            return (
                int.from_bytes(body[16:18], "little"),
                int.from_bytes(body[14:16], "little"),
                True,
            )
    raise CaptureFormatError(f"{name}: no UDP packet with a nexmon_csi magic (0x1111) in the pcap")


def chanspec_freq(chanspec: int) -> tuple[int, int]:
    """(centre frequency MHz, bandwidth MHz) of a Broadcom d11ac chanspec."""
    channel = chanspec & 0xFF
    bw = {0x0800: 20, 0x1000: 40, 0x1800: 40, 0x2000: 80, 0x2800: 160}.get(chanspec & 0x3800, 20)
    if chanspec & 0xC000 == 0xC000 or channel > 14:
        return 5000 + 5 * channel, bw
    return (2484 if channel == 14 else 2407 + 5 * channel), bw


def read_nexmon(path: str | Path, freq_mhz: int = 0, chip: str | None = None) -> CsiCapture:
    """Frames of a nexmon_csi pcap, packets grouped by (MAC, sequence) across cores.

    Raises:
        CaptureFormatError: not a nexmon pcap, unknown chip (pass ``chip``), or csiread fails.
        MissingDependencyError: csiread is not installed.
    """
    name = str(path)
    version, chanspec, new = _nexmon_header(name)
    chip = chip or NEXMON_CHIPS.get(version)
    if chip is None:
        raise CaptureFormatError(
            f"{name}: unknown nexmon chip_version 0x{version:04x}; name it with "
            f"chip= ({', '.join(sorted(set(NEXMON_CHIPS.values())))})"
        )
    centre, bw = chanspec_freq(chanspec)
    lib = _csiread()
    try:
        cls = lib.NexmonPull46 if new else lib.Nexmon
        d = cls(name, chip=chip, bw=bw, if_report=False)
        d.read()
    except Exception as err:
        raise _fail(name, "nexmon_csi", err) from err
    n = int(d.count)
    if n == 0:
        raise CaptureFormatError(f"{name}: no nexmon_csi packet decoded")
    mac = _macs(d.src_addr[:n])
    seq = np.asarray(d.seq[:n], np.int64)
    core = np.asarray(d.core[:n], np.int64)
    stream = np.asarray(d.spatial[:n], np.int64)
    # a frame ends where the transmitter or sequence changes or a (core, stream) repeats
    starts = [0]
    seen = {(int(core[0]), int(stream[0]))}
    for i in range(1, n):
        key = (int(core[i]), int(stream[i]))
        if mac[i] != mac[i - 1] or seq[i] != seq[i - 1] or key in seen:
            starts.append(i)
            seen = set()
        seen.add(key)
    group = np.zeros(n, np.int64)
    group[starts[1:]] = 1
    group = np.cumsum(group)
    nrx, ntx = int(core.max()) + 1, int(stream.max()) + 1
    nfft = d.csi.shape[1]
    frames = new_frames(
        "nexmon",
        len(starts),
        nrx,
        ntx,
        np.fft.fftshift(np.arange(nfft) - nfft // 2).astype(np.int16),
    )
    frames.h[group, core, stream, :] = np.asarray(d.csi[:n], np.complex64)
    frames.h[:, :, :, frames.subcarrier == 0] = 0
    first = np.asarray(starts)
    frames.mac[:] = mac[first]
    frames.seq[:] = (seq[first] >> 4).astype(np.int32)
    t = np.asarray(d.sec[:n], np.int64) * 1_000_000_000 + np.asarray(d.usec[:n], np.int64) * (
        1 if d.nano else 1000
    )
    frames.t_ns[:] = t[first]
    frames.freq_mhz[:] = centre or freq_mhz
    notes: Counter[str] = Counter()
    if new:
        rssi = np.asarray(d.rssi[:n], np.float32)
        frames.rssi_dbm[group, core] = rssi
    notes["packets"] = n
    caplen = np.asarray(d.caplen[:n])
    notes["packets longer than the CSI they carry"] = int(np.sum(caplen > np.median(caplen)))
    unit = "dBm" if new else "none (old nexmon format)"
    return CsiCapture(name, "nexmon", [frames], unit, [], notes)


READERS = {"atheros": "read_atheros", "picoscenes": "read_picoscenes", "nexmon": "read_nexmon"}
CHILD_TIMEOUT_S = 300.0
"""Longest a child process may take to parse one file."""


def _child(conn: Any, fmt: str, path: str, freq_mhz: int, chip: str | None) -> None:
    try:
        reader = globals()[READERS[fmt]]
        args: tuple[Any, ...] = (path, freq_mhz, chip) if fmt == "nexmon" else (path, freq_mhz)
        conn.send(("ok", reader(*args)))
    except RfsasError as err:
        conn.send(("error", err))
    except Exception as err:  # a bug or a csiread failure: report it, do not hang the parent
        conn.send(("error", CaptureFormatError(f"{path}: {type(err).__name__}: {err}")))
    finally:
        conn.close()


@contextlib.contextmanager
def _main_not_rerun() -> Iterator[None]:
    """Start a child without running the caller's script again in it.

    A child started by a fork server re-imports the parent's ``__main__``
    from its file (multiprocessing's "safe importing of main module"); a plain
    script without an ``if __name__ == "__main__":`` guard would then open its
    source again inside the child and fail. The child here only needs this
    module, so the script's path is hidden while the child starts.
    """
    main = sys.modules.get("__main__")
    if main is None or not hasattr(main, "__file__"):
        yield  # an interactive session: nothing would be run again
        return
    path, spec = main.__file__, getattr(main, "__spec__", None)
    del main.__file__
    main.__spec__ = None  # ``python -m script`` would be re-imported by name
    try:
        yield
    finally:
        main.__file__ = path
        main.__spec__ = spec


def read_isolated(
    fmt: str, path: str | Path, freq_mhz: int = 0, chip: str | None = None
) -> CsiCapture:
    """Run one of this module's readers in a child process.

    ``csiread`` is C code; on some corrupted files it crashes the process
    (a segmentation fault on a damaged PicoScenes file). In a child, such a
    crash costs that file only and becomes an error here.

    Raises:
        CaptureFormatError: the child crashed, timed out, or the file is bad.
        MissingDependencyError: csiread is not installed.
    """
    import multiprocessing

    if fmt not in READERS:
        raise ValueError(f"no csiread reader for {fmt!r}")
    _csiread()  # a missing dependency is reported here, with the install command
    # one fork server, started once with the parser loaded, forks a cheap child per file
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["csiread", "rfsas_hw.sources.csi_csiread"])
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(child, fmt, str(path), freq_mhz, chip), daemon=True)
    with _main_not_rerun():
        proc.start()
    child.close()
    try:
        if not parent.poll(CHILD_TIMEOUT_S):
            proc.kill()
            raise CaptureFormatError(f"{path}: csiread took over {CHILD_TIMEOUT_S:g} s; stopped")
        status, value = parent.recv()
    except EOFError:
        proc.join(5)
        raise CaptureFormatError(
            f"{path}: csiread crashed on this {fmt} file (exit code {proc.exitcode}): "
            "the file is damaged or not of this format"
        ) from None
    finally:
        parent.close()
        proc.join(5)
        if proc.is_alive():
            proc.kill()
            proc.join(5)
        proc.close()
    if status == "error":
        raise value
    capture: CsiCapture = value
    return capture
