"""The grading channel: messages between the grader and its child over two pipes.

A message is a JSON object whose numpy arrays travel as raw bytes after it: a 4-byte length, the
JSON header ``{"msg": ..., "arrays": [{"dtype", "shape"}, ...]}`` (an array in ``msg`` is
``{"__array__": k}``), then the arrays' bytes. Reading never unpickles and never trusts the
child: a header that is not JSON, an array of another dtype than floats, integers or booleans,
a shape that does not match its bytes or a message over :data:`MAX_BYTES` is a
:class:`ChannelError` (the grader makes it a failed claim with its reason); the end of the pipe is
:class:`ChannelClosed`; no message before the deadline is :class:`ChannelTimeout`.
"""
from __future__ import annotations

import json
import os
import select
import struct
import time

import numpy as np

MAX_BYTES = 1 << 28   # 256 MiB: more than any answer of a check needs
DTYPES = ("<f8", "<i8", "<i4", "|b1")


class ChannelError(Exception):
    """A malformed message."""


class ChannelClosed(ChannelError):
    """The other end closed the pipe (the child ended)."""


class ChannelTimeout(Exception):
    """No whole message came before the deadline."""


def _encode(obj, arrays: list):
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        if a.dtype.kind == "f":
            a = a.astype("<f8")
        elif a.dtype.kind in "iu":
            a = a.astype("<i8")
        elif a.dtype.kind == "b":
            a = a.astype("|b1")
        else:
            raise TypeError(f"cannot send an array of {a.dtype}")
        arrays.append(a)
        return {"__array__": len(arrays) - 1}
    if isinstance(obj, dict):
        return {str(k): _encode(v, arrays) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_encode(v, arrays) for v in obj]
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    return obj


def pack(msg) -> bytes:
    arrays: list = []
    body = _encode(msg, arrays)
    header = json.dumps({"msg": body, "arrays": [{"dtype": a.dtype.str, "shape": list(a.shape)} for a in arrays]},
                        allow_nan=True).encode("utf-8")
    return struct.pack(">I", len(header)) + header + b"".join(a.tobytes() for a in arrays)


def send(fd: int, msg, deadline: float | None = None) -> None:
    """Write one message; with a ``deadline`` (``time.monotonic()`` seconds) the pipe is written as
    it becomes writable and ChannelTimeout is raised when it stays full (a reader that stopped)."""
    data = memoryview(pack(msg))
    if deadline is not None:
        os.set_blocking(fd, False)
    while data:
        if deadline is not None:
            _, ready, _ = select.select([], [fd], [], max(0.0, deadline - time.monotonic()))
            if not ready:
                raise ChannelTimeout()
        try:
            n = os.write(fd, data)
        except BlockingIOError:
            continue
        data = data[n:]


def _decode(obj, arrays: list):
    if isinstance(obj, dict):
        if set(obj) == {"__array__"}:
            k = obj["__array__"]
            if not (isinstance(k, int) and 0 <= k < len(arrays)):
                raise ChannelError("an array reference out of range")
            return arrays[k]
        return {k: _decode(v, arrays) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_decode(v, arrays) for v in obj]
    return obj


class Reader:
    """Reads messages from ``fd`` with a deadline (``time.monotonic()`` seconds, or None)."""

    def __init__(self, fd: int):
        self.fd = fd
        self.buffer = bytearray()

    def _fill(self, n: int, deadline: float | None) -> None:
        while len(self.buffer) < n:
            wait = None if deadline is None else max(0.0, deadline - time.monotonic())
            ready, _, _ = select.select([self.fd], [], [], wait)
            if not ready:
                raise ChannelTimeout()
            chunk = os.read(self.fd, max(65536, min(n - len(self.buffer), 1 << 24)))
            if not chunk:
                raise ChannelClosed("the other end closed the channel")
            self.buffer += chunk

    def _take(self, n: int) -> bytes:
        out = bytes(self.buffer[:n])
        del self.buffer[:n]
        return out

    def read(self, deadline: float | None = None):
        self._fill(4, deadline)
        (size,) = struct.unpack(">I", bytes(self.buffer[:4]))
        if size > MAX_BYTES:
            raise ChannelError(f"a message header of {size} bytes")
        self._fill(4 + size, deadline)
        self._take(4)
        try:
            header = json.loads(self._take(size).decode("utf-8"))
        except (UnicodeDecodeError, ValueError, RecursionError) as exc:
            raise ChannelError(f"a message that is not JSON ({type(exc).__name__})") from None
        if not (isinstance(header, dict) and set(header) == {"msg", "arrays"} and isinstance(header["arrays"], list)):
            raise ChannelError("a message without its fields")
        arrays, total = [], 0
        for spec in header["arrays"]:
            if not (isinstance(spec, dict) and spec.get("dtype") in DTYPES and isinstance(spec.get("shape"), list)
                    and len(spec["shape"]) <= 8 and all(type(s) is int and 0 <= s < MAX_BYTES for s in spec["shape"])):
                raise ChannelError("an array of another kind than numbers")
            dtype = np.dtype(spec["dtype"])
            count = 1
            for n in spec["shape"]:   # in Python integers: no overflow
                count *= n
            nbytes = count * dtype.itemsize
            total += nbytes
            if total > MAX_BYTES:
                raise ChannelError("a message over the size limit")
            self._fill(nbytes, deadline)
            try:
                arrays.append(np.frombuffer(self._take(nbytes), dtype=dtype).reshape(spec["shape"]).copy())
            except ValueError as exc:
                raise ChannelError(f"an array that does not match its shape ({exc})") from None
        try:
            return _decode(header["msg"], arrays)
        except RecursionError:
            raise ChannelError("a message nested too deeply") from None
