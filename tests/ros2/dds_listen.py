"""A separate process that subscribes to the rfsas ROS 2 topics over loopback DDS.

Usage: ``python dds_listen.py DOMAIN_ID EXPECTED TIMEOUT_S``. Prints ``ready``
once its readers exist, then one JSON line per sample (topic and the hex of
the sample's XCDR1 serialisation) until EXPECTED samples arrived or
TIMEOUT_S passed, then ``done N``. Readers keep every sample (KEEP_ALL) so a
burst is never overwritten before it is taken.
"""

from __future__ import annotations

import json
import sys
import time

from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic as DdsTopic
from cyclonedds.util import duration

from rfsas_hw.ros2 import topics
from rfsas_hw.ros2.dds import DdsConfig, _participant, idl_class, is_state_change


def main() -> None:
    domain_id, expected, timeout_s = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
    _domain, participant = _participant(DdsConfig(domain_id=domain_id, interface="lo"))
    readers = {}
    for topic in topics.ALL:
        t = DdsTopic(participant, topic.dds_name, idl_class(topic.typename))
        qos = Qos(
            Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)),
            Policy.Durability.Volatile,
            Policy.History.KeepAll,
        )
        readers[topic.name] = DataReader(participant, t, qos=qos)
    print("ready", flush=True)
    got = 0
    deadline = time.monotonic() + timeout_s
    while got < expected and time.monotonic() < deadline:
        idle = True
        for name, reader in readers.items():
            for sample in reader.take(N=256):
                idle = False
                if is_state_change(sample):  # a writer that left, not a message
                    continue
                got += 1
                print(json.dumps({"topic": name, "cdr": sample.serialize().hex()}), flush=True)
        if idle:
            time.sleep(0.005)
    print(f"done {got}", flush=True)


if __name__ == "__main__":
    main()
