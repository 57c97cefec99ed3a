"""``flashnav bench ...``: the speed benchmarks (see :mod:`flashnav.bench.cli`)."""
