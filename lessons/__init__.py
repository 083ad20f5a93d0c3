"""The lessons, one package each, and their command line: ``python -m lessons`` (lessons/cli.py)."""
import engine  # noqa: F401  (first: it sets the BLAS threads' environment before numpy loads)
