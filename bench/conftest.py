"""Benchmarks and their correctness checks share the tests' runtime: CPU, 2 threads, f64
(override with ELASTIC_THREADS / ELASTIC_FP for the thread- and precision-variant runs)."""
import pytest

from engine import runtime


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime():
    return runtime.init()
