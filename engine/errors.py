"""Errors raised by GranLab.

Every error names what is wrong and what is allowed, so that a user typing a
value into the lab or a scene file knows how to fix it.
"""


def one_line(text: str) -> str:
    """``text`` on one line: what another library says (HDF5's errors run to several) joined by spaces."""
    return " ".join(text.split())


class GranLabError(Exception):
    """Base class of all GranLab errors."""


class ParameterError(GranLabError, ValueError):
    """An invalid parameter value.

    The message reads ``<name> = <value> is not allowed: <what is allowed>``.
    """

    def __init__(self, name: str, value, allowed: str):
        self.name = name
        self.value = value
        self.allowed = allowed
        super().__init__(f"{name} = {value!r} is not allowed: {allowed}")


class DivergenceError(GranLabError, RuntimeError):
    """The run diverged; the simulation keeps its last good state.

    Attributes: ``reason`` (text), ``step`` (the step at which the failure was
    seen) and ``time`` (the simulated time of the last good state).
    """

    def __init__(self, reason: str, step: int, time: float):
        self.reason = reason
        self.step = step
        self.time = time
        super().__init__(
            f"run diverged at step {step}: {reason}. "
            f"The simulation was restored to its last good state (t = {time:.6g})."
        )


class SceneError(GranLabError, ValueError):
    """A broken scene file: names the key and what is allowed."""


class OutputError(GranLabError, OSError):
    """An output that cannot be written, or would write over a file that was not given up."""


class WriteFailed(OutputError):
    """A run file's write failed on the way (a full disk, a file size limit, an I/O error). Its
    HDF5 handle is left as it is: closing it would write again, and h5py then crashes the process
    as it exits; a command ends the process at once after saying so (``os._exit``). The file reads
    up to what was written, as a killed writer's does."""

    def __init__(self, message: str, reason: str):
        super().__init__(message)
        self.reason = reason



class RegistryError(GranLabError, ImportError):
    """A part named in a registry (a contact law, a tangential model) whose module lacks what every
    part of its family defines: it does not register, and the engine does not import."""

    def __init__(self, family: str, name: str, module: str, missing: list[str], needed: str):
        super().__init__(f"{family} {name!r} does not register: its module {module} has no "
                         f"{', '.join(missing)} (each one defines {needed})")
