"""Explicit-vs-implicit benchmarks (pytest-benchmark) and their report: ``python -m bench``.
See bench/README.md."""
