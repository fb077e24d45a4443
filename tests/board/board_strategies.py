"""Hypothesis strategies for every board-protocol message (valid field ranges)."""

from __future__ import annotations

from hypothesis import strategies as st

from rfsas_hw.board.messages import (
    MAX_ERROR_TEXT,
    MAX_SCAN_CHANNELS,
    Ack,
    ErrorReport,
    Heartbeat,
    Hello,
    Info,
    Measurement,
    MeasurementBatch,
    Message,
    Nak,
    SetChannel,
    SetScanPlan,
    Start,
    Stop,
    TimeSync,
    TimeSyncRequest,
)

u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFF_FFFF)
u64 = st.integers(0, 2**64 - 1)
rssi = st.one_of(st.none(), st.integers(-127, 127))

measurements = st.builds(
    Measurement,
    t_us=u64,
    mac=st.integers(0, 2**48 - 1),
    freq_mhz=u16,
    channel=u8,
    kind=u8,
    flags=u8,
    frame_seq=st.one_of(st.none(), st.integers(0, 4095)),
    rssi_dbm=st.tuples(rssi, rssi, rssi, rssi),
)

texts = st.text(
    alphabet=st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=16
).filter(lambda s: len(s.encode("utf-8")) <= MAX_ERROR_TEXT)

messages: st.SearchStrategy[Message] = st.one_of(
    st.builds(Hello, u8),
    st.builds(Info, u8, u8, u8, u8, u8, u32, u64),
    measurements,
    st.builds(
        MeasurementBatch,
        st.lists(measurements, max_size=MeasurementBatch.MAX_COUNT).map(tuple),
    ),
    st.builds(SetChannel, u16),
    st.builds(SetScanPlan, u16, st.lists(u16, max_size=MAX_SCAN_CHANNELS).map(tuple)),
    st.builds(Start),
    st.builds(Stop),
    st.builds(Heartbeat, u64, u32, u32, u16, u16, u8, u16),
    st.builds(Ack, u16, u8),
    st.builds(Nak, u16, u8, u8, u16),
    st.builds(ErrorReport, u16, u32, texts),
    st.builds(TimeSyncRequest, u64),
    st.builds(TimeSync, u64, u64, u64),
)
