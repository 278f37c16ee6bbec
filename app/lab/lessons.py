"""Lesson sheets: for each preset one printable page of predict–observe–explain steps, read from
``static/teaching/lessons/<preset>.md`` into a :class:`Lesson` and written as HTML.

A sheet is Markdown in a fixed layout, so that the lab can read it::

    # <title>

    <the introduction: one or more paragraphs>

    ## Step 1: <title>
    **Do:** what to do in the lab: which control, which value
    **Ask:** the question the students answer before they look (their prediction)
    **See:** what they should see, with numbers
    **Time:** about <N> s (what runs, in the preset's simulated time)
    **Answer:** the physics, for the teacher
    **Paper:** the figure or equation of the papers the step reproduces
    **Check:** the id of the test that runs the step headless (tests/test_lessons.py)

Every step has these seven fields in this order; a field may go on over several lines, and
blank lines may separate fields and steps. Steps are numbered 1, 2, ... A sheet that breaks the
layout raises :class:`LessonError` naming its file and line. Inline Markdown (``code``,
``**bold**``, ``*italic*``) is rendered; nothing else is needed on one page.

Pure Python (no UI library): the dashboard shows :func:`lesson_html` in a pane, a print route
serves the standalone page.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from html import escape
from pathlib import Path
from typing import NoReturn

STATIC = Path(__file__).resolve().parents[2] / "static"
LESSONS = STATIC / "teaching" / "lessons"
FIELDS = ("do", "ask", "see", "time", "answer", "paper", "check")
"""The fields of a step, in the order a sheet gives them."""
FIELD_LINE = re.compile(r"\*\*(\w+):\*\*\s*(.*)")
STEP_LINE = re.compile(r"## Step (\d+):\s*(.*)")
SECONDS = re.compile(r"(?:about )?(\d+(?:\.\d+)?) s\b")
"""The wall-clock seconds a step's Time starts with."""
CHECK_ID = re.compile(r"[a-z0-9][a-z0-9-]*")
PRESET_NAME = re.compile(r"[a-z0-9][a-z0-9-]*")


class LessonError(ValueError):
    """A lesson sheet that breaks the layout (the message names its file and line)."""


@dataclass(frozen=True)
class Step:
    """One predict–observe–explain step: what to ``do`` in the lab, what to ``ask`` the students,
    what they should ``see``, how long it takes (``time``, at the preset's default speed), the
    ``answer`` for the teacher, the ``paper``'s figure or equation and the ``check`` that tests it."""

    title: str
    do: str
    ask: str
    see: str
    time: str
    answer: str
    paper: str
    check: str

    @property
    def seconds(self) -> float:
        """The wall-clock seconds the step takes, as its Time says."""
        return float(SECONDS.match(self.time).group(1))


@dataclass(frozen=True)
class Lesson:
    """The sheet of ``preset``: its ``title``, ``intro`` (paragraphs separated by blank lines)
    and ``steps``."""

    title: str
    preset: str
    intro: str
    steps: tuple[Step, ...]

    @property
    def seconds(self) -> float:
        return sum(step.seconds for step in self.steps)


def sheet_path(preset: str) -> Path | None:
    """The sheet of ``preset``, None for a name that cannot be a preset's (no folders, no dots)."""
    return LESSONS / f"{preset}.md" if isinstance(preset, str) and PRESET_NAME.fullmatch(preset) else None


def lesson(preset: str) -> Lesson | None:
    """The lesson sheet of ``preset``, None if it has none."""
    path = sheet_path(preset)
    if path is None or not path.is_file():
        return None
    return parse_lesson(path.read_text(encoding="utf-8"), preset, path)


def lesson_presets() -> tuple[str, ...]:
    """The presets that have a sheet."""
    return tuple(sorted(path.stem for path in LESSONS.glob("*.md") if PRESET_NAME.fullmatch(path.stem)))


def parse_lesson(text: str, preset: str, path: Path | str = "<lesson>") -> Lesson:
    """Read a sheet's ``text`` (see the module's docstring); ``path`` names it in errors."""
    shown = _shown(Path(path))
    lines = text.splitlines()

    def fail(number: int, what: str) -> NoReturn:
        raise LessonError(f"{shown}, line {number}: {what}")

    numbered = [(number, line.rstrip()) for number, line in enumerate(lines, 1)]
    first = next((k for k, (_, line) in enumerate(numbered) if line.strip()), None)
    if first is None or not numbered[first][1].startswith("# "):
        fail(1 if first is None else numbered[first][0], "a sheet starts with its title, '# <title>'")
    title = numbered[first][1][2:].strip()
    steps_at = [k for k, (_, line) in enumerate(numbered) if line.startswith("## ")]
    intro = "\n".join(line for _, line in numbered[first + 1:steps_at[0] if steps_at else None]).strip()
    if not intro:
        fail(numbered[first][0] + 1, "the title is followed by an introduction (a paragraph) before "
                                     "'## Step 1: <title>'")
    if not steps_at:
        fail(len(lines), "a sheet has at least one step, '## Step 1: <title>'")
    steps = []
    for k, start in enumerate(steps_at):
        end = steps_at[k + 1] if k + 1 < len(steps_at) else len(numbered)
        steps.append(_step(numbered[start:end], len(steps) + 1, fail))
    checks = [step.check for step in steps]
    for k, check in enumerate(checks):
        if check in checks[:k]:
            fail(numbered[steps_at[k]][0],
                 f"step {k + 1} repeats the check {check!r} of step {checks.index(check) + 1}")
    return Lesson(title=title, preset=preset, intro=intro, steps=tuple(steps))


def _step(block: list[tuple[int, str]], expected: int, fail) -> Step:
    """The step of ``block`` (its heading and the lines up to the next heading)."""
    number, heading = block[0]
    match = STEP_LINE.fullmatch(heading)
    if match is None or not match.group(2).strip():
        fail(number, f"a step starts with '## Step {expected}: <title>', not {heading!r}")
    if int(match.group(1)) != expected:
        fail(number, f"steps are numbered in order: this is step {expected}, not {match.group(1)}")
    values: dict[str, list[str]] = {}
    lines: dict[str, int] = {}
    last = number
    for number, line in block[1:]:
        if not line.strip():
            continue
        last = number
        field = FIELD_LINE.match(line)
        if field is None:
            if not values:
                fail(number, f"step {expected} goes on with '**Do:** ...', not {line.strip()!r}")
            values[next(reversed(values))].append(line.strip())
            continue
        name = field.group(1).lower()
        wanted = FIELDS[len(values)] if len(values) < len(FIELDS) else None
        if name != wanted:
            what = f"'**{wanted.capitalize()}:** ...'" if wanted else "the next '## Step'"
            fail(number, f"step {expected}: expected {what} here, not '**{field.group(1)}:**' (the fields are "
                         f"{', '.join(f.capitalize() for f in FIELDS)}, in this order)")
        values[name] = [field.group(2).strip()]
        lines[name] = number
    missing = [f for f in FIELDS if f not in values]
    if missing:
        fail(last, f"step {expected} ends without '**{missing[0].capitalize()}:** ...'")
    text = {name: " ".join(part for part in parts if part) for name, parts in values.items()}
    for name in FIELDS:
        if not text[name]:
            fail(lines[name], f"step {expected}: its {name.capitalize()} is empty")
    if not SECONDS.match(text["time"]):
        fail(lines["time"], f"step {expected}: its Time starts with the seconds it takes, 'about 12 s (...)', not "
                            f"{text['time']!r}")
    if not CHECK_ID.fullmatch(text["check"]):
        fail(lines["check"], f"step {expected}: its Check is one id of lower-case letters, digits and '-', not "
                             f"{text['check']!r}")
    return Step(title=match.group(2).strip(), **text)


def _shown(path: Path) -> str:
    """``path`` from the checkout's root when it lies inside it (``static/teaching/lessons/x.md``)."""
    try:
        return str(path.resolve().relative_to(STATIC.parent))
    except ValueError:
        return str(path)


INLINE = (
    (re.compile(r"`([^`]+)`"), r"<code>\1</code>"),
    (re.compile(r"\*\*(.+?)\*\*"), r"<strong>\1</strong>"),
    (re.compile(r"(?<![\w*])\*(?!\s)(.+?)(?<!\s)\*(?![\w*])"), r"<em>\1</em>"),
)


def inline(text: str) -> str:
    """HTML of one field: escaped, with inline Markdown (``code``, ``**bold**``, ``*italic*``)."""
    html = escape(text, quote=False)
    for pattern, replacement in INLINE:
        html = pattern.sub(replacement, html)
    return html


CSS = """
.granlab-lesson { font-family: "DejaVu Sans", "Helvetica Neue", Arial, sans-serif; font-size: 10pt;
  line-height: 1.3; color: #111; }
.granlab-lesson h1 { font-size: 14pt; margin: 0 0 3pt 0; }
.granlab-lesson .lesson-intro p { margin: 0 0 4pt 0; }
.granlab-lesson .lesson-legend { font-size: 8.5pt; color: #555; margin: 0 0 5pt 0; }
.granlab-lesson .lesson-step { border-top: 1.5pt solid #333; padding-top: 3pt; margin-top: 5pt;
  break-inside: avoid; page-break-inside: avoid; }
.granlab-lesson h2 { font-size: 11pt; margin: 0 0 2pt 0; }
.granlab-lesson .lesson-meta { font-size: 8.5pt; color: #444; margin: 0 0 2pt 0; }
.granlab-lesson .lesson-body { display: grid; grid-template-columns: 1fr 1.3fr; gap: 6pt; }
.granlab-lesson .lesson-body p { margin: 0 0 3pt 0; }
.granlab-lesson .lesson-teacher { background: #f4efe1; border-left: 3pt solid #b08d2b; padding: 2pt 5pt;
  font-size: 9pt; -webkit-print-color-adjust: exact; print-color-adjust: exact; }
.granlab-lesson .lesson-teacher::before { content: "For the teacher"; display: block; font-size: 7.5pt;
  font-weight: bold; letter-spacing: 0.05em; text-transform: uppercase; color: #8a6a12; }
.granlab-lesson code { font-size: 90%; }
"""
PRINT_CSS = """
@page { margin: 11mm 12mm; }
html, body { margin: 0; padding: 0; background: #fff; }
@media screen { body { max-width: 186mm; margin: 8mm auto; } }
@media print { .granlab-lesson { font-size: 9pt; } .granlab-lesson .lesson-teacher { font-size: 8.3pt; } }
"""
"""The standalone page: one A4 or Letter sheet (186 × 257 mm inside the margins fits both)."""


def lesson_html(lesson: Lesson, standalone: bool = False) -> str:
    """The sheet as HTML: each step's Do and Ask for the class beside its See and Answer in a shaded
    box for the teacher (class ``lesson-teacher``, which a page may hide from students). With
    ``standalone`` a whole page that prints on one A4 or Letter sheet and asks nothing of any host."""
    parts = [f'<div class="granlab-lesson" data-preset="{escape(lesson.preset)}">',
             f"<h1>{inline(lesson.title)}</h1>",
             '<div class="lesson-intro">' + "".join(f"<p>{inline(' '.join(paragraph.split()))}</p>"
                                                    for paragraph in re.split(r"\n\s*\n", lesson.intro)) + "</div>",
             f'<p class="lesson-legend">{len(lesson.steps)} steps, about {lesson.seconds:.0f} s of the lab at its '
             f"default speed. Ask first, then play: the shaded boxes are for the teacher.</p>"]
    for number, step in enumerate(lesson.steps, 1):
        parts.append(
            f'<section class="lesson-step" data-check="{escape(step.check)}">'
            f"<h2>{number}. {inline(step.title)}</h2>"
            f'<p class="lesson-meta"><strong>Time:</strong> {inline(step.time)} · <strong>Paper:</strong> '
            f"{inline(step.paper)}</p>"
            f'<div class="lesson-body"><div class="lesson-class"><p><strong>Do:</strong> {inline(step.do)}</p>'
            f"<p><strong>Ask:</strong> {inline(step.ask)}</p></div>"
            f'<div class="lesson-teacher"><p><strong>See:</strong> {inline(step.see)}</p>'
            f"<p><strong>Answer:</strong> {inline(step.answer)}</p></div></div></section>")
    parts.append("</div>")
    body = "".join(parts)
    if not standalone:
        return f"<style>{CSS}</style>{body}"
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>{escape(lesson.title)}</title>'
            f"<style>{CSS}{PRINT_CSS}</style></head><body>{body}</body></html>")
