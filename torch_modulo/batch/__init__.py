"""A batch engine for folders of files: one job per input, run safely, in parallel, resumably, on one or many machines.

The engine knows nothing about images: a command (``torch-modulo simulate``, ``unwrap``, ``tonemap``) lists its
inputs as :class:`Task` objects (an input and the output paths it produces) and passes a top-level job function;
:func:`run_batch` does the rest.

What it guarantees
    - **Inputs are never written.** :func:`check_folders` refuses an output folder equal to or inside the input
      folder, and a task whose output would land inside the input folder (or replace one of its inputs) fails
      without running.
    - **Each input once.** :func:`discover` follows symbolic links but never enters a folder twice, so a link
      loop or a second link to the same file cannot repeat an input.
    - **Atomic outputs.** Jobs write files with :func:`torch_modulo.io.write_image` (a temporary file renamed
      into place) and folders in a hidden temporary folder renamed into place (:func:`atomic_output_dir`, or for
      frame stacks ``write_frames``' swap, which keeps the folder's other entries), so a crash never leaves a
      half-written output under its final name. What a killed run leaves behind (hidden temporaries) is removed
      by the next run.
    - **Resume.** After a task succeeds the engine writes a small *done marker* under
      ``OUT/.torch-modulo/<command>/`` (atomically) that records the options, the input's size and modification
      time, and the outputs. A task is *complete*, and skipped by the next run, when its marker exists, matches
      the current options and input, and every output exists. A rerun after a crash or Ctrl-C therefore redoes
      only what is missing; changing an option or the input redoes that task; ``force=True`` redoes everything.
    - **Failures are contained.** An exception in one job is recorded with its message (``"OSError: cannot read
      image ..."``, naming final paths, never temporary ones) and the other tasks go on. A done marker that
      cannot be written (a full disk) fails its task the same way.
    - **A report.** ``done``, ``skipped`` and ``failed`` (with reasons) and, after an interruption, the tasks not
      finished, written atomically as JSON (:class:`BatchReport`). A report that cannot be written is said on
      stderr and makes the exit code 1.
    - **Ctrl-C** (SIGINT, and SIGTERM as sent by schedulers and ``torchrun``), at any time, including while the
      worker pool starts: tasks not yet started are cancelled, running ones are allowed to finish (a second
      Ctrl-C abandons them), completed outputs are kept and the report says what was done (exit code 130).

The package's rooms: :mod:`~torch_modulo.batch.tasks` (tasks, discovery, folder checks),
:mod:`~torch_modulo.batch.atomic` (the atomic writes and clean-up of :mod:`torch_modulo._atomic`, re-exported),
:mod:`~torch_modulo.batch.markers` (resume),
:mod:`~torch_modulo.batch.report`, :mod:`~torch_modulo.batch.engines` (inline, process pool, Ray; Ctrl-C),
:mod:`~torch_modulo.batch.distributed` (torchrun: shares and report parts) and :mod:`~torch_modulo.batch.run`
(:func:`run_batch`: plan, execute, finish).
"""

from __future__ import annotations

from torch_modulo._atomic import atomic_output_dir, remove_stale_temporaries, write_json
from torch_modulo.batch.distributed import DistributedEnv, balance, distributed_env, shard
from torch_modulo.batch.engines import ENGINES, default_workers, require_ray
from torch_modulo.batch.markers import MARKER_FOLDER
from torch_modulo.batch.report import BatchReport, merge_reports
from torch_modulo.batch.run import run_batch
from torch_modulo.batch.tasks import BatchError, JobFunction, Task, check_folders, discover

__all__ = [
    "ENGINES",
    "MARKER_FOLDER",
    "BatchError",
    "BatchReport",
    "DistributedEnv",
    "JobFunction",
    "Task",
    "atomic_output_dir",
    "balance",
    "check_folders",
    "default_workers",
    "discover",
    "distributed_env",
    "merge_reports",
    "remove_stale_temporaries",
    "require_ray",
    "run_batch",
    "shard",
    "write_json",
]
