"""The application around the lessons: the command line (``python -m lessons``), the lesson
registry, what the lessons run on, the Rerun recorder and the output files."""
