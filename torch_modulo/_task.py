"""A :class:`Task`: one input and the outputs it produces, the unit of work the jobs and the batch engine share.

The jobs of :mod:`torch_modulo.pipeline` take one and :mod:`torch_modulo.batch` runs them on many; both import it
from here (it is :class:`torch_modulo.batch.Task` too), so a job does not depend on the engine.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Task"]


@dataclass(frozen=True)
class Task:
    """One unit of work: an input and the outputs it produces.

    Args:
        name: the input's path relative to the input folder, with ``/`` separators (``"sub/scene.exr"``); the
            key in the report and in the done markers.
        source: the input file or folder (absolute path as a string, so tasks pickle cheaply).
        outputs: the paths (files or folders) the job creates, absolute.

    Example:
        >>> Task("a.exr", "/data/in/a.exr", ("/data/out/a.png",)).name
        'a.exr'
    """

    name: str
    source: str
    outputs: tuple[str, ...]

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"Task.name must be a non-empty string; got {self.name!r}")
        if not self.outputs:
            raise ValueError(f"Task {self.name!r} must have at least one output")
        object.__setattr__(self, "source", str(self.source))
        object.__setattr__(self, "outputs", tuple(str(p) for p in self.outputs))
