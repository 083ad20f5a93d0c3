"""Explicit-vs-implicit benchmarks (pytest-benchmark) and their report: ``python -m bench``.
See bench/README.md."""
import engine  # noqa: F401  (first: it sets the BLAS threads' environment before numpy loads)
