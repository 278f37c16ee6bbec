"""Who is told of this package's compiles: :data:`WATCHERS`, filled by
:func:`granlab.engine.compilation.announced` and told by :mod:`.jit`'s listener. A module of its
own, importing nothing, so that a command can watch before it knows whether it will load numba."""

WATCHERS: list = []
"""Objects with ``started(name)`` (the outermost compile of a kernel of this package begins) and
``ended()`` (it ended)."""
