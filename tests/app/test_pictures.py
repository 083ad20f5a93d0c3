"""python -m lessons.tools.pictures refuses a recording that rerun's reader cannot read (corrupted,
truncated, not a recording) at once, in one line, exit 2, before starting the viewer or writing
anything: the viewer would wait out --timeout for it. No viewer is needed for these."""
import time

import numpy as np
import pytest

from lessons.tools import pictures
from lessons.tools.viewer_processes import unreadable_recording
from tests.helpers import write_points_recording


@pytest.fixture(scope="module")
def good_rrd(tmp_path_factory):
    """A small recording written by the SDK (points over 20 steps; smooth, so that it is compressed)."""
    return write_points_recording(tmp_path_factory.mktemp("rrd") / "good.rrd", app="elastic_lessons_test_pictures")


def _corrupt(good: bytes, how: str) -> bytes:
    if how == "garbage":
        return np.random.default_rng(1).bytes(50_000)
    if how == "text":
        return b"not a recording\n" * 100
    if how == "empty":
        return b""
    if how == "truncated":
        return good[:len(good) // 2]
    flipped = bytearray(good)  # "flipped": bytes of the first messages changed (their framing breaks; bytes
    for i in range(1000, 5000):  # flipped deep inside one chunk's literals can read as other data, and are shown)
        flipped[i] ^= 0x5A
    return bytes(flipped)


def test_a_good_recording_reads(good_rrd):
    assert unreadable_recording(good_rrd) is None


@pytest.mark.parametrize("how,needle", [
    ("garbage", 'Not an RRD file: expected FourCC header "RRF2"'),
    ("text", 'Not an RRD file: expected FourCC header "RRF2", got "not "'),
    ("empty", "file too small to be an RRD"),
    ("truncated", "exceeds file size"),
    ("flipped", "Codec error"),
])
def test_a_corrupted_recording_is_refused_at_once_in_one_line(tmp_path, monkeypatch, capsys, good_rrd, how, needle):
    bad = tmp_path / "springs.rrd"
    bad.write_bytes(_corrupt(good_rrd.read_bytes(), how))
    monkeypatch.chdir(tmp_path)
    t0 = time.monotonic()
    rc = pictures.main(["springs.rrd", "--out", "pics", "--timeout", "20"])
    took = time.monotonic() - t0
    captured = capsys.readouterr()
    assert rc == 2, captured
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("python -m lessons.tools.pictures: springs.rrd is not a readable Rerun recording (")
    assert needle in lines[0] and lines[0].endswith("; record it again: python -m lessons run LESSON --record "
                                                    "springs.rrd")
    assert took < 5, took  # not --timeout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["springs.rrd"]  # --out not even created
