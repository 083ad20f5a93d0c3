"""One check of a student's solution, in its own process (lessons.app.grading starts it and stops
it at its time limit).

    python -m lessons.app.grading_child LESSON SOLUTION_FILE OUT_FILE units NAME...
    python -m lessons.app.grading_child LESSON SOLUTION_FILE OUT_FILE stages N1,N2,... NAME...

``units``: each named function's own checks, one after the other. ``stages``: the lesson's stages,
one after the other, with the named functions in the engine's place. Every line of OUT_FILE is one JSON object:
``{"start": name}`` before a function's checks (so that a time-out names the function),
``{"task": name, "rows": [...]}`` or ``{"task": name, "error": "one line"}`` after them,
``{"start": "stage N"}`` before a stage, ``{"stage": N, "rows": [...]}`` or ``{"stage": N, "error": ...}``
after it.
"""
import io
import json
import sys


def _line(out, obj) -> None:
    out.write(json.dumps(obj) + "\n")
    out.flush()


def _one_line(exc: BaseException, name: str) -> str:
    from .._exercise import StudentError
    if isinstance(exc, StudentError):
        return str(exc)
    text = " ".join(str(exc).split())
    return f"{name}: raised {type(exc).__name__}: {text[:4000]}"


def main(argv: list[str]) -> int:
    lesson_id, solution, out_path, mode, *rest = argv
    from engine import runtime
    runtime.init()
    from .._exercise import load_before_swap, load_student_module
    from . import registry
    from .exercises import exercise_module

    lesson = registry.get(lesson_id)
    tasks = {t.name: t for t in exercise_module(lesson).TASKS}
    with open(out_path, "a", encoding="utf-8") as out:
        try:
            student = load_student_module(solution)
        except BaseException as exc:  # noqa: BLE001 - any failure of the student's module is reported
            _line(out, {"error": f"{solution}: could not be imported: {type(exc).__name__}: "
                                 f"{' '.join(str(exc).split())[:240]}"})
            return 0
        if mode == "units":
            for name in rest:
                _line(out, {"start": name})
                try:
                    rows = [e.to_dict(lesson.id, 0, "your functions") for e in tasks[name].check(getattr(student, name))]
                    _line(out, {"task": name, "rows": rows})
                except Exception as exc:  # noqa: BLE001
                    _line(out, {"task": name, "error": _one_line(exc, name)})
            return 0
        stages = [int(s) for s in rest[0].split(",")]
        names = rest[1:]
        load_before_swap(f"lessons.{lesson.id.replace('-', '_')}")
        module = exercise_module(lesson)
        for name in names:
            tasks[name].install(getattr(student, name))
        if hasattr(module, "finish_install"):
            module.finish_install()
        from .._framework import run_lesson
        from .recorder import NullRecorder
        cfg = lesson.config()
        for stage in stages:
            _line(out, {"start": f"stage {stage}"})
            rows: list = []
            try:
                run_lesson(lesson, cfg, NullRecorder(), [stage], out=io.StringIO(), err=io.StringIO(), quiet=True,
                           results=rows)
                _line(out, {"stage": stage, "rows": rows})
            except Exception as exc:  # noqa: BLE001
                _line(out, {"stage": stage, "error": _one_line(exc, f"stage {stage}")})
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
