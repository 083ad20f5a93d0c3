"""Where a part run by ``python -m bench`` puts its result: the file named by ``--json``, or stdout."""
import json


def emit_json(obj, path=None) -> int:
    """Write ``obj`` as indented JSON to ``path``, or print it to stdout when there is none.
    Returns 0, the exit status of a part that got this far."""
    text = json.dumps(obj, indent=1)
    if path:
        with open(path, "w") as fh:
            fh.write(text)
    else:
        print(text)
    return 0
