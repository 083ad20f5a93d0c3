"""The grading child: the only process that runs the student's code (lessons.app.grading_remote starts it,
talks to it over two pipes and stops it at its time limits).

    python -m lessons.app.grading_child LESSON SOLUTION_FILE IN_FD OUT_FD GRADER_PID CPU_S MEMORY_BYTES

It ends itself with the grader and runs under CPU-time and memory limits; starts Taichi and loads
the engine and the lesson; arms the guard (lessons.app.sandbox_guard); imports the student's module with
restricted builtins; says ``{"ready": ..., "notes": [...], "own": {name: why not}}`` (or
``{"error": line}``) and then answers requests, one at a time (lessons.app.channel):

- ``{"op": "call", "task", "factory", "args", "inputs"}``: the lesson's ``factory(func, *args)`` (a
  kernel built around the student's function, or the function itself) called on ``inputs``;
  answers ``{"ok": array or [arrays]}`` or ``{"error": line}``. The checks and their verdicts
  stay with the grader: this process sees inputs and returns outputs, nothing else.
- ``{"op": "install", "names"}``: the student's functions in the engine's place; ``{"ok": true}``.
- ``{"op": "stage", "index"}``: one stage of the lesson on them; ``{"rows": [...]}`` or
  ``{"error": line}`` (the grader validates the rows and recomputes each verdict).

After each request the guard compares numpy, math and taichi with what they were: a change ends the
process with ``{"violation": line}``, and so does anything the audit hook refuses.
"""
import importlib
import io
import os
import sys


def _one_line(exc: BaseException, name: str) -> str:
    from .._exercise import StudentError
    if isinstance(exc, StudentError):
        return str(exc)
    text = " ".join(str(exc).split())
    return f"{name}: raised {type(exc).__name__}: {text[:4000]}"


def _factory(spec: str):
    module, _, name = spec.partition(":")
    if not module.startswith("lessons."):
        raise ValueError(f"factory {spec!r} is not the lessons'")
    return getattr(importlib.import_module(module), name)


def main(argv: list[str]) -> int:
    lesson_id, solution, in_fd, out_fd, grader_pid, cpu_s, memory = argv
    in_fd, out_fd = int(in_fd), int(out_fd)
    from .sandbox_guard import limit_child
    limit_child(int(grader_pid), float(cpu_s), int(memory) or None)
    from . import channel
    reader = channel.Reader(in_fd)

    def send(msg) -> None:
        channel.send(out_fd, msg)

    from engine import runtime
    runtime.init()
    from .._exercise import StudentError, call_student, direct, load_before_swap, normalise_result
    from . import registry
    from .exercises import exercise_module
    from .sandbox_guard import Guard, load_guarded, own_function

    lesson = registry.get(lesson_id)
    module = exercise_module(lesson)
    tasks = {t.name: t for t in module.TASKS}
    load_before_swap(f"lessons.{lesson.id.replace('-', '_')}")
    from .._framework import run_lesson
    from .recorder import NullRecorder

    guard = Guard(lambda why: send({"violation": why}))
    guard.arm()
    try:
        student, files = load_guarded(solution, guard.files)
    except BaseException as exc:  # noqa: BLE001 - any failure of the student's module is reported
        send({"error": f"{os.path.basename(solution)}: could not be imported: {type(exc).__name__}: "
                       f"{' '.join(str(exc).split())[:240]}"})
        return 0
    changed = guard.tampered()
    if changed:
        guard.refuse(changed)
    send({"ready": True, "notes": list(guard.notes), "own": {n: own_function(student, n, files) for n in tasks}})
    built: dict = {}
    while True:
        try:
            request = reader.read()
        except channel.ChannelClosed:
            return 0
        op = request.get("op")
        if op == "call":
            name = request["task"]
            factory = _factory(request["factory"])
            key = (name, request["factory"], tuple(request["args"]))
            kernel = factory is not direct
            try:
                if key not in built:
                    built[key] = factory(getattr(student, name), *request["args"])
                result = call_student(name, built[key], *request["inputs"], kernel=kernel)
                out = normalise_result(name, result, kernel)
                answer = {"ok": list(out) if isinstance(out, tuple) else out, "tuple": isinstance(out, tuple)}
            except StudentError as exc:
                answer = {"error": str(exc)}
            except Exception as exc:  # noqa: BLE001
                answer = {"error": _one_line(exc, name)}
        elif op == "install":
            for name in request["names"]:
                tasks[name].install(getattr(student, name))
            if hasattr(module, "finish_install"):
                module.finish_install()
            answer = {"ok": True}
        elif op == "stage":
            index = int(request["index"])
            rows: list = []
            try:
                run_lesson(lesson, lesson.config(), NullRecorder(), [index], out=io.StringIO(), err=io.StringIO(),
                           quiet=True, results=rows)
                answer = {"rows": rows}
            except Exception as exc:  # noqa: BLE001
                answer = {"error": _one_line(exc, f"stage {index}")}
        else:
            return 0
        changed = guard.tampered()
        if changed:
            guard.refuse(changed)
        if guard.notes:
            answer["notes"] = list(guard.notes)
            guard.notes.clear()
        send(answer)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
