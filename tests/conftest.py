"""Shared fixtures: one Taichi runtime per test session (CPU, 2 threads, f64)."""
import pytest

from engine import runtime


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime():
    return runtime.init()
