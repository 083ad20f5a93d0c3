"""``python -m bench.report RAW_DIR [--out DIR] [--no-latest]``: re-render a run's report."""
import sys

from bench.report import main

sys.exit(main())
