"""The lessons, one package each, and their command line: ``python -m lessons`` (lessons/app/cli.py)."""
import engine  # noqa: F401  (first: it sets the BLAS threads' environment before numpy loads)
