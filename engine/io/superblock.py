"""The superblock of an HDF5 file (versions 2 and 3, which SWMR needs): where it records its end of
file and whether it is being written, and a read-only view of a file whose writer was killed as if
the writer had closed it.

HDF5 refuses to open a file still marked as being written except as a SWMR reader, and a SWMR
reader retries a read whose checksum fails for ever: a damaged file left by a killed writer would
hang its reader. :class:`FinishedWriteView` clears the mark in what HDF5 reads (the file itself is
not touched), so that HDF5 reads it as a closed file and names the damage instead.
"""

from __future__ import annotations

import io
from pathlib import Path

SIGNATURE = b"\x89HDF\r\n\x1a\n"
HEAD = 48
"""Bytes of a version 2 or 3 superblock with 8-byte addresses: signature, version, sizes, flags,
four addresses (base, extension, end of file, root group), checksum."""
FLAGS = 11
CHECKSUM = 44


def find(path: Path) -> tuple[int, bytes] | None:
    """(offset, the HEAD bytes) of the file's version 2 or 3 superblock with 8-byte addresses, at
    the offsets HDF5 allows (0, 512, 1024, ...); None if there is none."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        offset = 0
        while offset + HEAD <= size:
            f.seek(offset)
            head = f.read(HEAD)
            if head[:8] == SIGNATURE:
                return (offset, head) if head[8] in (2, 3) and head[9] == 8 else None
            offset = 512 if offset == 0 else 2 * offset
    return None


def stored_eof(path: Path) -> int:
    """The end of file the superblock records (0 without a version 2 or 3 superblock)."""
    found = find(path)
    if found is None:
        return 0
    base, _extension, eof = (int.from_bytes(found[1][k:k + 8], "little") for k in (12, 20, 28))
    return base + eof


def left_open(path: Path) -> bool:
    """Whether the superblock says a writer has the file open (a live writer, or one that died)."""
    found = find(path)
    return found is not None and found[1][FLAGS] != 0


def _rotate(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & 0xFFFFFFFF


def lookup3(data: bytes, initial: int = 0) -> int:
    """Bob Jenkins' lookup3 ``hashlittle``: the checksum of HDF5's metadata."""
    mask = 0xFFFFFFFF
    length, k = len(data), 0
    a = b = c = (0xDEADBEEF + length + initial) & mask
    while length > 12:
        a = (a + int.from_bytes(data[k:k + 4], "little")) & mask
        b = (b + int.from_bytes(data[k + 4:k + 8], "little")) & mask
        c = (c + int.from_bytes(data[k + 8:k + 12], "little")) & mask
        for x, y, z, shift in ((0, 2, 1, 4), (1, 0, 2, 6), (2, 1, 0, 8), (0, 2, 1, 16), (1, 0, 2, 19), (2, 1, 0, 4)):
            v = [a, b, c]
            v[x] = ((v[x] - v[y]) & mask) ^ _rotate(v[y], shift)
            v[y] = (v[y] + v[z]) & mask
            a, b, c = v
        length -= 12
        k += 12
    if length == 0:
        return c
    tail = data[k:] + bytes(12 - length)
    a = (a + int.from_bytes(tail[0:4], "little")) & mask
    b = (b + int.from_bytes(tail[4:8], "little")) & mask
    c = (c + int.from_bytes(tail[8:12], "little")) & mask
    for x, y, shift in ((2, 1, 14), (0, 2, 11), (1, 0, 25), (2, 1, 16), (0, 2, 4), (1, 0, 14), (2, 1, 24)):
        v = [a, b, c]
        v[x] = ((v[x] ^ v[y]) - _rotate(v[y], shift)) & mask
        a, b, c = v
    return c


class FinishedWriteView(io.RawIOBase):
    """The file at ``path`` as HDF5 reads it, its superblock's 'being written' flags cleared, its
    end of file at most the file's size (a writer stopped by a full disk records more than it could
    write) and its checksum made anew: a file whose writer is gone, read as if the writer had
    closed it. What lay past the end then reads as damaged, not as missing for ever."""

    def __init__(self, path: Path):
        super().__init__()
        self.path = Path(path)
        found = find(self.path)
        if found is None:
            raise ValueError(f"{str(path)!r} has no version 2 or 3 HDF5 superblock")
        self._at, head = found
        head = bytearray(head)
        head[FLAGS] = 0
        base = int.from_bytes(head[12:20], "little")
        eof = min(int.from_bytes(head[28:36], "little"), self.path.stat().st_size - base)
        head[28:36] = eof.to_bytes(8, "little")
        head[CHECKSUM:HEAD] = lookup3(bytes(head[:CHECKSUM])).to_bytes(4, "little")
        self._head = bytes(head)
        self._file = open(self.path, "rb")

    def __repr__(self) -> str:
        return str(self.path)  # what h5py calls the file's name

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        return self._file.seek(offset, whence)

    def tell(self) -> int:
        return self._file.tell()

    def readinto(self, buffer) -> int:
        start = self._file.tell()
        count = self._file.readinto(buffer)
        low, high = max(start, self._at), min(start + count, self._at + HEAD)
        if low < high:
            memoryview(buffer).cast("B")[low - start:high - start] = self._head[low - self._at:high - self._at]
        return count

    def close(self) -> None:
        self._file.close()
        super().close()
