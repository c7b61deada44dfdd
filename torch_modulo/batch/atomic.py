"""The atomic writes the batch engine uses, importable here as well: they live in :mod:`torch_modulo._atomic`.

Every write goes to a hidden temporary name beside its final name and is renamed into place, so a reader never sees
half a file; :func:`remove_stale_temporaries` deletes what a killed writer left, and errors name final paths.
"""

from __future__ import annotations

from torch_modulo._atomic import (
    atomic_output_dir,
    final_names,
    free_space_note,
    remove_stale_temporaries,
    write_bytes,
    write_json,
)

__all__ = [
    "atomic_output_dir",
    "final_names",
    "free_space_note",
    "remove_stale_temporaries",
    "write_bytes",
    "write_json",
]
