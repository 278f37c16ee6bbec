"""Ring buffers of time-series rows with sequence numbers (one writer, many readers).

The engine thread appends rows (numbers only); each browser session remembers the last
sequence number it has seen and asks for the rows after it, however many arrived meanwhile
(up to the capacity: a reader that fell further behind gets the newest ``capacity`` rows). A
reset (new preset, reset, replay) starts a new generation: a reader of an older generation
gets everything again and a ``reset`` flag. Rows live in one preallocated float64 array, so
appending and reading cost a copy, not a Python object per value; the array is written through when it
is made, so its memory is taken then, not page by page as rows come (a lab's resident memory grew for
half an hour as its buffers filled, 5 MiB a minute with the ratchet's 78 MiB of them).
"""

from __future__ import annotations

import itertools
import threading
from dataclasses import dataclass

import numpy as np

_GENERATIONS = itertools.count(1)
"""Generations are numbered across buffers: a reader of a buffer since dropped and made again (a preset
left and come back to) is never taken for one of the new buffer's."""


@dataclass(frozen=True)
class Cursor:
    """Where a reader stands: the generation it read and the last sequence number it got; ``run``,
    the run (preset, restart or replay) whose rows the buffer held then."""

    generation: int = -1
    seq: int = 0
    run: int = 0


class SeriesBuffer:
    """Rows of one series with sequence numbers; the oldest dropped beyond ``capacity``."""

    def __init__(self, columns: tuple[str, ...], capacity: int = 20000):
        self.columns = tuple(columns)
        self.capacity = int(capacity)
        self._data = _rows(self.capacity, len(self.columns))
        self._seq = 0
        self._generation = next(_GENERATIONS)
        self._run = 0
        self._lock = threading.Lock()

    def extend(self, rows) -> None:
        """Append rows (a sequence of tuples, or an (R, C) array); only the newest ``capacity``
        of them are kept."""
        block = np.asarray(rows, dtype=np.float64).reshape(-1, len(self.columns))[-self.capacity:]
        with self._lock:
            start = self._seq % self.capacity
            first = min(len(block), self.capacity - start)
            self._data[start:start + first] = block[:first]
            self._data[:len(block) - first] = block[first:]
            self._seq += len(block)

    def reset(self, columns: tuple[str, ...] | None = None, run: int | None = None) -> None:
        """Drop every row and start a new generation (optionally with other columns, for another ``run``)."""
        with self._lock:
            self._seq = 0
            self._generation = next(_GENERATIONS)
            self._run = self._run if run is None else run
            if columns is not None and tuple(columns) != self.columns:
                self.columns = tuple(columns)
                self._data = _rows(self.capacity, len(self.columns))

    def _rows_after(self, seq: int) -> np.ndarray:
        """Rows with sequence numbers above ``seq`` still held, oldest first (lock held)."""
        count = min(self._seq - seq, self._seq, self.capacity)
        if count <= 0:
            return np.zeros((0, len(self.columns)))
        index = np.arange(self._seq - count, self._seq) % self.capacity
        return self._data[index]

    def since(self, cursor: Cursor) -> tuple[Cursor, bool, dict[str, np.ndarray]]:
        """Rows after ``cursor`` as columns (float64 arrays); ``reset`` is true when the reader
        must start over."""
        with self._lock:
            reset = cursor.generation != self._generation
            rows = self._rows_after(0 if reset else cursor.seq)
            new = Cursor(self._generation, self._seq, self._run)
            names = self.columns
        return new, reset, dict(zip(names, rows.T.copy()))

    def array(self) -> np.ndarray:
        """Every row held, oldest first, as an (R, C) array (a copy)."""
        with self._lock:
            return self._rows_after(0).copy()

    def __len__(self) -> int:
        with self._lock:
            return min(self._seq, self.capacity)

    @property
    def nbytes(self) -> int:
        """The memory its rows take, held or not."""
        return self._data.nbytes


def _rows(capacity: int, columns: int) -> np.ndarray:
    """``capacity`` rows of zeros, every page of them written (``np.zeros`` leaves them to be taken as used)."""
    return np.full((capacity, columns), 0.0)


@dataclass(frozen=True)
class Message:
    """A message for the user: ``level`` (info, warning, error), ``text`` and the ``control``
    that caused it (a settings key such as ``amplitude``, or ``save``, ``load``, ``watch``,
    ``preset``, ``run``, ``analysis``, ``record``), so a page shows it next to that control."""

    seq: int
    level: str
    text: str
    control: str = ""


class MessageLog:
    """The last ``capacity`` messages with sequence numbers (one writer, many readers)."""

    def __init__(self, capacity: int = 200):
        self._messages: list[Message] = []
        self._seq = 0
        self.capacity = capacity
        self._lock = threading.Lock()

    def add(self, level: str, text: str, control: str = "") -> None:
        with self._lock:
            self._seq += 1
            self._messages = self._messages[-(self.capacity - 1):] + [Message(self._seq, level, text, control)]

    @property
    def latest_seq(self) -> int:
        return self._seq

    def since(self, seq: int) -> list[Message]:
        """Messages after sequence number ``seq``, oldest first."""
        with self._lock:
            return [m for m in self._messages if m.seq > seq]
