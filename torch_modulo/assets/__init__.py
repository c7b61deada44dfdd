"""Data shipped with the package: one small CC0 HDR scene for the demo, examples and tests."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["DEFAULT_SCENE", "default_scene_path"]

#: File name of the embedded scene (Poly Haven "apartment", CC0; see README.md beside it).
DEFAULT_SCENE = "apartment.exr"


def default_scene_path() -> Path:
    """Path of the embedded default scene (a 512x256 HDR panorama, CC0).

    Example:
        >>> default_scene_path().name
        'apartment.exr'
    """
    return Path(str(resources.files(__package__).joinpath(DEFAULT_SCENE)))
