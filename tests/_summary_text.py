"""What a printed summary must hold: every parameter value with its standard deviation."""

from __future__ import annotations

import re

_VALUE = re.compile(r"(-?\d[\d.e+-]*) (kg|N/m|N s/m|N s/m per kg|N/m per kg)\b")


def values_without_std(text: str) -> list[str]:
    """Lines with a number in a parameter's unit that is not preceded by 'x +- s'."""
    bad = []
    for line in text.splitlines():
        for m in _VALUE.finditer(line):
            before = line[: m.start(2)]
            if not re.search(r"\+- *[\d.e+-]+ *$", before) and "added" not in before[-20:]:
                bad.append(line.strip())
    return bad
