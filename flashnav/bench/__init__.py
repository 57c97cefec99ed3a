"""``flashnav bench ...``: the speed benchmarks (see :mod:`flashnav.bench.cli`)."""

from __future__ import annotations


def parse_names(text: str, allowed, flag: str) -> list[str]:
    """``"a, b"`` -> ``["a", "b"]``, each one of ``allowed``; a ValueError names the unknown ones and ``flag``."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    bad = [n for n in names if n not in allowed]
    if bad or not names:
        raise ValueError(f"{flag}: unknown {', '.join(bad) or '(empty)'}; use some of {', '.join(allowed)}")
    return names
