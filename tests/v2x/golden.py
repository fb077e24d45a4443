"""The golden CPM vectors: name → the sample CPM its bytes encode.

``python tests/v2x/golden.py`` writes them to tests/data/v2x/ (run it only when the
encoding changes on purpose, and say why in the commit).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from cpmhelp import sample_cpm

from rfsas_hw.v2x.model import Cpm

GOLDEN_DIR = Path(__file__).resolve().parents[1] / "data" / "v2x"

GOLDEN: dict[str, Cpm] = {
    "rsu_0_objects": sample_cpm(0),
    "rsu_1_object": sample_cpm(1),
    "rsu_20_objects": sample_cpm(20),
    "rsu_1_object_no_correlation": sample_cpm(1, correlation=False),
    "rsu_20_objects_no_correlation": sample_cpm(20, correlation=False),
    "rsu_20_objects_no_sensors": sample_cpm(20, sensors=False),
    "vehicle_0_objects": sample_cpm(0, vehicle=True),
    "vehicle_1_object": sample_cpm(1, vehicle=True),
    "vehicle_20_objects": sample_cpm(20, vehicle=True),
    "rsu_segment_1_of_2": sample_cpm(10, segment=(1, 2)),
    "rsu_segment_2_of_2": sample_cpm(10, sensors=False, segment=(2, 2)),
}


def main() -> None:
    from rfsas_hw.v2x.codec import encode_cpm

    GOLDEN_DIR.mkdir(parents=True, exist_ok=True)
    for name, cpm in GOLDEN.items():
        (GOLDEN_DIR / f"{name}.uper").write_bytes(encode_cpm(cpm))


if __name__ == "__main__":
    main()
