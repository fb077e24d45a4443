"""The independent second decoder: pycrate compiled from the official ASN.1 modules.

pycrate needs three mechanical edits of the modules before it compiles them (none
changes a PER-visible constraint): the CDD is read as latin-1 (its comments hold
CP1252 bytes); unions of ``WITH COMPONENTS`` constraints (not PER-visible) are
dropped; the inner ``SIZE(3..16,...)`` of ``PolygonalShape.polygon`` is dropped.
The generated module is written once per test session.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

ASN1_DIR = Path(__file__).resolve().parents[2] / "rfsas_hw" / "v2x" / "asn1"


def _drop_component_unions(text: str) -> str:
    """Remove every parenthesised union of ``WITH COMPONENT(S)`` constraints."""
    out: list[str] = []
    i = 0
    opener = re.compile(r"\(\s*\(\s*WITH COMPONENTS?\b")
    while True:
        m = opener.search(text, i)
        if m is None:
            out.append(text[i:])
            return "".join(out)
        depth = 0
        j = m.start()
        while True:
            if text[j] == "(":
                depth += 1
            elif text[j] == ")":
                depth -= 1
                if depth == 0:
                    break
            j += 1
        body = text[m.start() : j + 1]
        out.append(text[i : m.start()])
        if "|" not in body:
            out.append(body)
        i = j + 1


def edited_modules() -> str:
    """The modules as one text, with the three edits applied."""
    texts = [p.read_bytes().decode("latin-1") for p in sorted(ASN1_DIR.glob("*.asn"))]
    text = _drop_component_unions("\n".join(texts))
    return text.replace(
        "SequenceOfCartesianPosition3d (SIZE(3..16,...))", "SequenceOfCartesianPosition3d"
    )


def compile_pycrate(out_dir: Path) -> ModuleType:
    """Compile the modules with pycrate into ``out_dir`` and import the result."""
    from pycrate_asn1c.asnproc import GLOBAL, PycrateGenerator, compile_text, generate_modules

    GLOBAL.clear()
    compile_text(edited_modules())
    target = out_dir / "its_cpm_pycrate.py"
    generate_modules(PycrateGenerator, str(target))
    GLOBAL.clear()
    spec = importlib.util.spec_from_file_location("its_cpm_pycrate", target)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["its_cpm_pycrate"] = module
    spec.loader.exec_module(module)
    return module


class PycrateCpm:
    """Decode and re-encode CPMs (and their wrapped containers) with pycrate."""

    def __init__(self, module: ModuleType) -> None:
        pdu = module.CPM_PDU_Descriptions
        self._cpm = pdu.CollectivePerceptionMessage
        self._module = module

    def decode(self, data: bytes) -> Any:
        self._cpm.from_uper(data)
        return self._cpm.get_val()

    def reencode(self, data: bytes) -> bytes:
        self._cpm.from_uper(data)
        value = self._cpm.get_val()
        self._cpm.set_val(value)
        return bytes(self._cpm.to_uper())

    def encode(self, value: Any) -> bytes:
        """UPER of a value in pycrate's form (as :meth:`decode` gives it)."""
        self._cpm.set_val(value)
        return bytes(self._cpm.to_uper())
