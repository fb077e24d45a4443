"""The shipped message definitions and the Foxglove layout."""

from __future__ import annotations

import json
import re
from typing import Any

import pytest

pytest.importorskip("rosbags", reason="needs the ros2 extra: pip install 'rfsas-hw[ros2]'")
pytest.importorskip("mcap_ros2", reason="needs the ros2 extra: pip install 'rfsas-hw[ros2]'")

from mcap_ros2._dynamic import generate_dynamic

from rfsas_hw.ros2 import topics
from rfsas_hw.ros2.foxglove_live import LAYOUT_FILE
from rfsas_hw.ros2.types import (
    RFSAS_MSGS_VERSION,
    msgdef,
    shipped_definitions,
    typestore,
)


def test_every_rfsas_message_is_versioned_and_has_no_mac_field() -> None:
    defs = shipped_definitions()
    rfsas = {k: v for k, v in defs.items() if k.startswith("rfsas_msgs/")}
    assert len(rfsas) == 8
    store = typestore()
    for name, text in rfsas.items():
        consts, fields = store.fielddefs[name]
        assert ("VERSION", "uint8", RFSAS_MSGS_VERSION) in consts, name
        for field, _ in fields:
            assert not re.search(r"mac|address", field, re.IGNORECASE), (name, field)
        assert not re.search(r"^\s*\w+(\[\])?\s+\w*mac\w*\s*$", text, re.IGNORECASE | re.MULTILINE)


@pytest.mark.parametrize("topic", topics.ALL, ids=lambda t: t.name)
def test_schema_text_parses_in_an_independent_parser(topic: topics.Topic) -> None:
    """The ros2msg schema the recordings carry is read by mcap-ros2-support's parser."""
    decoders = generate_dynamic(topic.typename, msgdef(topic.typename))
    assert topic.typename in decoders


def _panels(node: Any) -> list[str]:
    if isinstance(node, str):
        return [node]
    return _panels(node["first"]) + _panels(node["second"])


def test_layout_panels_and_topics_exist() -> None:
    layout = json.loads(LAYOUT_FILE.read_text())
    panels = _panels(layout["layout"])
    assert set(panels) == set(layout["configById"])
    assert any(p.startswith("3D!") for p in panels)
    names = {t.name for t in topics.ALL}
    text = json.dumps(layout["configById"])
    referenced = set(re.findall(r'"(/(?:rfsas/\w+|diagnostics))', text))
    assert referenced and referenced <= names
    # message paths name real fields: /rfsas/assessments.assessments[0].<field>
    store = typestore()
    fields = {f for f, _ in store.fielddefs["rfsas_msgs/msg/Assessment"][1]}
    for path in re.findall(r"/rfsas/assessments\.assessments\[0\]\.(\w+)", text):
        assert path in fields
    assert layout["configById"]["3D!rfsas-scene"]["followTf"] == "map"
