"""Which frames of a run file a command reads (``--frames K`` or ``A:B:S``) and its progress as it
reads them: shared by ``granlab export`` and ``granlab render``, so both take the same frames."""

from __future__ import annotations

from collections.abc import Callable, Iterator

from ..errors import ParameterError


def select_frames(spec, count: int, name: str = "frames") -> list[int]:
    """Indices of the frames of a file of ``count`` frames that ``spec`` selects: a frame ``K``
    or a range ``A:B:S`` (Python's slice; negative counts from the end; S > 0), as text, an int
    or a slice. A range reaching outside the file or selecting nothing is refused."""
    if isinstance(spec, slice):
        text = ":".join("" if v is None else str(v) for v in (spec.start, spec.stop, spec.step))
    else:
        text = str(spec)
    last = count - 1
    allowed = f"a frame K or a range A:B:S (S > 0) within the file's frames 0..{last}, negative counting from the end"
    parts = text.split(":")
    try:
        values = [int(part) if part.strip() else None for part in parts]
    except ValueError:
        raise ParameterError(name, text, allowed) from None
    if len(values) > 3 or (len(values) == 1 and values[0] is None):
        raise ParameterError(name, text, allowed)
    if len(values) == 1:
        if not -count <= values[0] < count:
            raise ParameterError(name, text, allowed)
        return [values[0] % count]
    start, stop, step = (values + [None])[:3]
    if ((step is not None and step <= 0) or (start is not None and not -count <= start < count)
            or (stop is not None and not -count <= stop <= count)):
        raise ParameterError(name, text, allowed)
    indices = list(range(count))[start:stop:step]
    if not indices:
        raise ParameterError(name, text, f"a range selecting at least one of the file's frames 0..{last}")
    return indices


def reporting(frames: Iterator, total: int, progress: Callable[[int, int], None]) -> Iterator:
    """``frames``, calling ``progress(done, total)`` as each one is taken (the caller reports the
    end: a writer may stop asking after the last frame)."""
    for done, frame in enumerate(frames):
        progress(done, total)
        yield frame
