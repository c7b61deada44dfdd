"""Each folder command's tasks: the inputs ``simulate``, ``unwrap`` and ``tonemap`` take from a folder, the
outputs each writes, and what a task weighs when ranks share the work.

The command line lists a command's tasks with :func:`folder_tasks` and hands them, with the command's job from
:mod:`torch_modulo.pipeline`, to :func:`torch_modulo.batch.run_batch`, which weighs them with :func:`count_values`
under ``torchrun``.

Example:
    >>> import os, tempfile
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     for name in ("a.exr", "sub/b.hdr", "notes.txt"):
    ...         os.makedirs(os.path.dirname(os.path.join(folder, "in", name)), exist_ok=True)
    ...         open(os.path.join(folder, "in", name), "w").close()
    ...     tasks, wanted = folder_tasks("tonemap", Path(folder, "in"), Path(folder, "out"))
    ...     [(t.name, os.path.relpath(t.outputs[0], folder)) for t in tasks]
    [('a.exr', 'out/a.png'), ('sub/b.hdr', 'out/sub/b.png')]
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from torch_modulo._task import Task
from torch_modulo.batch.tasks import discover
from torch_modulo.radiance import RADIANCE_EXTENSIONS
from torch_modulo.sensors.files import MANIFEST, frame_bits, frame_exposure, stack_files
from torch_modulo.sensors.manifest import TRUTH_FILE

__all__ = ["CONFIDENCE_UNIT", "MODULUS_EXTENSIONS", "count_values", "folder_tasks", "not_radiance", "radiance_tasks"]

#: Modulus images ``unwrap --single`` reads.
MODULUS_EXTENSIONS = (".exr", ".png", ".tif", ".tiff", ".pfm")
#: The unit ``unwrap --confidence`` records in its confidence maps.
CONFIDENCE_UNIT = "confidence in [0, 1]"


def not_radiance(path: str | Path, listed: set[str] | None = None) -> str | None:
    """Why the image file ``path`` is not radiance by its own record, or None when nothing says so.

    A file is a frame when the ``frames.json`` beside it lists it, or when its metadata records a bit depth and an
    exposure but no unit (as :func:`~torch_modulo.sensors.write_frames` writes frames; radiance from ``unwrap``
    records ``"unit"``); it is a confidence map when its metadata's unit is :data:`CONFIDENCE_UNIT`. A file whose
    header cannot be read is left for the job to refuse with its own message. ``listed``: the names
    :func:`~torch_modulo.sensors.stack_files` gives for ``path``'s folder, when the caller has them already.

    Example:
        >>> import os, tempfile, torch
        >>> from torch_modulo.io import write_image
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     path = write_image(os.path.join(folder, "c.exr"), torch.zeros(1, 2, 2), {"unit": CONFIDENCE_UNIT})
        ...     not_radiance(path)
        'a confidence map (unwrap --confidence), values in [0, 1]'
    """
    from torch_modulo.io import read_metadata

    path = Path(path)
    listed = stack_files(path.parent) if listed is None else listed
    if path.name != TRUTH_FILE and path.name in listed - {MANIFEST}:
        return f"a frame of a modulo camera, listed in {path.parent / MANIFEST}: unwrap the stack, then tone-map that"
    try:
        meta = read_metadata(path)
        if meta.get("unit") == CONFIDENCE_UNIT:
            return "a confidence map (unwrap --confidence), values in [0, 1]"
        framed = frame_bits(meta, path) is not None and frame_exposure(meta, path) is not None
    except (OSError, ValueError):
        return None
    if framed and meta.get("unit") is None:
        return "a frame of a modulo camera (its metadata records bits and exposure, no unit): unwrap it first"
    return None


def radiance_tasks(tasks: Sequence[Task], out: Path) -> tuple[list[Task], list[dict[str, Any]]]:
    """The tasks whose inputs are radiance, and report entries (``input``, ``outputs``, ``reason``) for the others:
    frames and confidence maps, which ``tonemap`` skips (:func:`not_radiance`)."""
    kept, skipped = [], []
    listings: dict[Path, set[str]] = {}  # each folder's frames.json is read once, not once per file
    for task in tasks:
        folder = Path(task.source).parent
        if folder not in listings:
            listings[folder] = stack_files(folder)
        reason = not_radiance(task.source, listings[folder])
        if reason is None:
            kept.append(task)
        else:
            outputs = [os.path.relpath(o, out) for o in task.outputs]
            skipped.append({"input": task.name, "outputs": outputs, "reason": f"not radiance: {reason}"})
    return kept, skipped


def folder_tasks(
    command: str, source: Path, out: Path, *, single: bool = False, confidence: bool = False
) -> tuple[list[Task], str]:
    """The tasks of folder command ``command`` (sorted by input name) and a description of the inputs it wants.

    ``simulate``: every radiance file -> the frame-stack folder ``out/<name>/``; ``tonemap``: every radiance file
    -> ``out/<name>.png``; ``unwrap``: every frame stack (folder with a ``frames.json``) -> ``out/<stack>.exr``,
    or with ``single`` every frame stack and every modulus image outside the stacks -> ``out/<name>.exr`` (and
    ``out/<name>.confidence.exr`` with ``confidence``). Output paths mirror the input's subfolders.

    Raises:
        FileNotFoundError: ``source`` does not exist.
        OSError: a folder cannot be listed.
    """

    def suffix_match(extensions: Sequence[str]) -> Callable[[Path], bool]:
        # A broken link with a matching name is an input too: its job fails naming it, rather than it vanishing.
        return lambda p: (p.is_file() or (p.is_symlink() and not p.exists())) and p.suffix.lower() in extensions

    def is_stack(p: Path) -> bool:
        return p.is_dir() and (p / MANIFEST).is_file()

    if command in ("simulate", "tonemap"):
        found = discover(source, suffix_match(RADIANCE_EXTENSIONS))
        wanted = f"radiance files ({' '.join(RADIANCE_EXTENSIONS)})"
    elif single:
        # A stack is one input (its frame, scored against its truth); the files inside it are not inputs.
        image = suffix_match(MODULUS_EXTENSIONS)
        found = discover(source, lambda p: is_stack(p) or image(p))
        wanted = f"frame stacks or modulus images ({' '.join(MODULUS_EXTENSIONS)})"
    else:
        found = discover(source, is_stack)
        wanted = f"frame stacks (folders with a {MANIFEST} manifest)"
    tasks = []
    for name, path in found:
        rel = Path(name)
        if command == "simulate":
            target = out / rel.with_suffix("")
        elif command == "unwrap":
            stack = not single or path.is_dir()
            target = out / (rel.with_name(rel.name + ".exr") if stack else rel.with_suffix(".exr"))
        else:
            target = out / rel.with_suffix(".png")
        targets = [target]
        if command == "unwrap" and single and confidence:
            targets.append(target.with_name(f"{target.stem}.confidence.exr"))
        tasks.append(Task(name, str(path), tuple(str(t) for t in targets)))
    return tasks, wanted


def count_values(task: Task) -> float:
    """What a task costs when ranks share the work: the number of values (pixels times channels) of its input
    file, or of the image files in its input folder (from the files' headers; 0 for unreadable ones)."""
    import OpenImageIO as oiio

    source = Path(task.source)
    files = [source] if not source.is_dir() else sorted(p for p in source.iterdir() if not p.name.startswith("."))
    total = 0
    for path in files:
        if path.suffix.lower() == ".json" or not path.is_file():
            continue
        image = oiio.ImageInput.open(str(path))
        if image is None:
            oiio.geterror()  # clear the error OpenImageIO keeps for the next caller
            continue
        spec = image.spec()
        total += spec.width * spec.height * spec.nchannels
        image.close()
    return float(total)
