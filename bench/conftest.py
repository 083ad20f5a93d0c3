"""Benchmarks and their correctness checks share the tests' runtime: CPU, 2 threads, f64
(override with ELASTIC_THREADS / ELASTIC_FP for the thread- and precision-variant runs).

In the plain ``pytest`` run (pytest-benchmark disabled by the project's addopts) the benchmark
bodies run once each on tiny scenes (profile "smoke"); with ``--benchmark-enable`` the profile
is "quick" unless ELASTIC_BENCH_PROFILE says otherwise (bench/config.py)."""
import pytest

from bench import config as bench_config
from engine import runtime


def pytest_configure(config):
    disabled = config.getoption("benchmark_disable", False) and not config.getoption("benchmark_enable", False)
    if not disabled and (config.getoption("numprocesses", None) or 0) != 0:
        # the project's addopts run the tests on two pytest-xdist workers; timings taken beside another
        # worker would mean nothing (and pytest-benchmark would silently switch itself off)
        raise pytest.UsageError("timed benchmarks need one process: add -n 0 (python -m bench does)")
    bench_config.set_default_profile(not disabled)


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime():
    return runtime.init()  # engine.runtime finalises Taichi at exit, which writes the kernel cache
