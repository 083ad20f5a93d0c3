"""Tools around the recordings: the real Rerun viewer, headless (the tests look at the recordings
with it), and the README's pictures (``python -m lessons.tools.pictures``). The lessons never
import them."""
