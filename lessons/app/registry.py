"""Finds the lessons: every package inside ``lessons`` (not starting with "_", not app/ or tools/) that
defines ``LESSON``."""
from __future__ import annotations

import importlib
import pkgutil

import lessons
from .._framework import Lesson

NOT_LESSONS = ("app", "tools")  # the application and its tools, beside the lessons


def all_lessons() -> list[Lesson]:
    found = []
    for info in pkgutil.iter_modules(lessons.__path__):
        if not info.ispkg or info.name.startswith("_") or info.name in NOT_LESSONS:
            continue
        module = importlib.import_module(f"lessons.{info.name}")
        lesson = getattr(module, "LESSON", None)
        if isinstance(lesson, Lesson):
            found.append(lesson)
    return sorted(found, key=lambda l: (l.order, l.id))


def get(lesson_id: str) -> Lesson:
    lessons_ = {l.id: l for l in all_lessons()}
    if lesson_id not in lessons_:
        raise KeyError(lesson_id)
    return lessons_[lesson_id]
