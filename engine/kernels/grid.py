"""Kernels on a periodic grid, for the fractal analysis (:mod:`granlab.engine.analysis.fractal`,
Gilabert Sec. V): painting the disks, summing a spectrum by shells of |k|, and the moments of
labelled holes."""

import math

from .jit import JIT, njit


@njit(**JIT)
def paint_disks(positions, radii, dx, dy, field):
    """Set ``field[i, j] = 1`` at every cell centre ``((i + 1/2) dx, (j + 1/2) dy)`` inside a disk,
    the grid being periodic. Positions must lie in the box."""
    nx, ny = field.shape
    for p in range(radii.shape[0]):
        cx, cy, r = positions[p, 0], positions[p, 1], radii[p]
        i0 = int(math.ceil((cx - r) / dx - 0.5))
        i1 = int(math.floor((cx + r) / dx - 0.5))
        for i in range(i0, i1 + 1):
            u = (i + 0.5) * dx - cx
            h2 = r * r - u * u
            if h2 < 0.0:
                continue
            h = math.sqrt(h2)
            j0 = int(math.ceil((cy - h) / dy - 0.5))
            j1 = int(math.floor((cy + h) / dy - 0.5))
            count = j1 - j0 + 1
            if count <= 0:
                continue
            row = i % nx
            if count >= ny:
                field[row, :] = 1
                continue
            start = j0 % ny
            stop = start + count
            field[row, start:min(stop, ny)] = 1
            if stop > ny:
                field[row, :stop - ny] = 1


@njit(**JIT)
def shell_sums(spectrum, ny, kx_unit, ky_unit, dk, count, k_sum, power_sum):
    """Accumulate, per shell ``s = round(|k| / dk)``, the number of wavevectors, the sum of ``|k|``
    and of ``|F|²`` over a real-to-complex spectrum ``(nx, ny // 2 + 1)``; every column but the
    first and (``ny`` even) the last stands for two wavevectors ``±k``. ``k = 0`` is skipped."""
    nx, columns = spectrum.shape
    for i in range(nx):
        kx = (i if i <= nx // 2 else i - nx) * kx_unit
        for j in range(columns):
            if i == 0 and j == 0:
                continue
            ky = j * ky_unit
            k = math.sqrt(kx * kx + ky * ky)
            weight = 1.0 if j == 0 or 2 * j == ny else 2.0
            s = int(k / dk + 0.5)
            value = spectrum[i, j]
            count[s] += weight
            k_sum[s] += weight * k
            power_sum[s] += weight * (value.real * value.real + value.imag * value.imag)


@njit(**JIT)
def label_moments(labels, count, sum_i, sum_j, sum_ii, sum_jj):
    """Per label (> 0): number of cells and the sums of the cell indices i, j and of their squares."""
    nx, ny = labels.shape
    for i in range(nx):
        for j in range(ny):
            label = labels[i, j]
            if label > 0:
                count[label] += 1.0
                sum_i[label] += i
                sum_j[label] += j
                sum_ii[label] += i * i
                sum_jj[label] += j * j
