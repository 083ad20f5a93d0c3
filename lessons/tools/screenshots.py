"""The viewer's screenshots as pictures: PNG decoding, the background colour, the share of
pixels drawn over it (an empty view gives about 0), the PNG's size."""
from __future__ import annotations

import io

# A pixel is "drawn" when one of its channels differs from the background by more than this
# (0-255). Measured on the viewer's dark theme: the 3D grid lines and the faint plot grid stay
# below it (background 13, grid up to ~55: the lines' antialiased cores reach ~45 over the
# background), meshes, lines, points and text are far above.
DRAWN_TOLERANCE = 48


def decode_png(png: bytes):
    """RGB pixels (H x W x 3 uint8 numpy array) of a PNG."""
    import numpy as np
    from PIL import Image  # Pillow comes with matplotlib, a dependency of the project
    with Image.open(io.BytesIO(png)) as im:
        return np.asarray(im.convert("RGB"))


def background_colour(rgb) -> tuple[int, int, int]:
    """The most common colour of the picture: the view's background."""
    import numpy as np
    flat = rgb.reshape(-1, 3)
    packed = (flat[:, 0].astype(np.uint32) << 16) | (flat[:, 1].astype(np.uint32) << 8) | flat[:, 2]
    values, counts = np.unique(packed, return_counts=True)
    top = int(values[counts.argmax()])
    return (top >> 16) & 255, (top >> 8) & 255, top & 255


def drawn_fraction(png: bytes, tolerance: int = DRAWN_TOLERANCE, margin: int = 2) -> float:
    """Fraction of the pixels (``margin`` pixels at each border left out: the view's frame)
    whose colour differs from the dominant (background) colour by more than ``tolerance`` in
    some channel. An empty 3D view (background and grid) gives about 0; geometry gives its
    share of the picture."""
    import numpy as np
    rgb = decode_png(png)
    if margin and rgb.shape[0] > 2 * margin and rgb.shape[1] > 2 * margin:
        rgb = rgb[margin:-margin, margin:-margin]
    if rgb.size == 0:
        return 0.0
    bg = np.array(background_colour(rgb), dtype=np.int16)
    diff = np.abs(rgb.astype(np.int16) - bg).max(axis=2)
    return float((diff > tolerance).mean())


def png_size(png: bytes) -> tuple[int, int]:
    """(width, height) from the PNG header."""
    if png[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError("not a PNG")
    return int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")

