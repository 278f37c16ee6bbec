"""Ring buffers of time-series rows with sequence numbers (one writer, many readers).

The engine thread appends rows; each browser session remembers the last sequence number it
has seen and asks for the rows after it. A reset (new preset, reset, replay) starts a new
generation: a reader of an older generation gets everything again and a ``reset`` flag.
Readers never hold the lock longer than a copy of the rows they asked for.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass


@dataclass(frozen=True)
class Cursor:
    """Where a reader stands: the generation it read and the last sequence number it got."""

    generation: int = -1
    seq: int = 0


class SeriesBuffer:
    """Rows of one series with sequence numbers; the oldest dropped beyond ``capacity``."""

    def __init__(self, columns: tuple[str, ...], capacity: int = 20000):
        self.columns = tuple(columns)
        self._rows: deque = deque(maxlen=capacity)
        self._seq = 0
        self._generation = 0
        self._lock = threading.Lock()

    def extend(self, rows: list[tuple]) -> None:
        with self._lock:
            for row in rows:
                self._seq += 1
                self._rows.append((self._seq, row))

    def reset(self, columns: tuple[str, ...] | None = None) -> None:
        """Drop every row and start a new generation (optionally with other columns)."""
        with self._lock:
            self._rows.clear()
            self._generation += 1
            if columns is not None:
                self.columns = tuple(columns)

    def since(self, cursor: Cursor) -> tuple[Cursor, bool, dict[str, list]]:
        """Rows after ``cursor`` as columns; ``reset`` is true when the reader must start over."""
        with self._lock:
            reset = cursor.generation != self._generation
            seq = 0 if reset else cursor.seq
            count = len(self._rows)
            first = self._seq - count + 1  # sequence numbers in the buffer are contiguous
            start = max(0, seq + 1 - first)
            rows = [self._rows[k][1] for k in range(start, count)]
            new = Cursor(self._generation, self._seq)
            columns_names = self.columns
        columns = {name: [row[index] for row in rows] for index, name in enumerate(columns_names)}
        return new, reset, columns

    def __len__(self) -> int:
        return len(self._rows)
