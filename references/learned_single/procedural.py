"""Procedural HDR scenes for training: sky gradients, windows, light sources with glare, shaded textured surfaces.

Every scene is (3, size, size) float32 linear radiance > 0 in arbitrary units; the training script picks the
exposure. Seeded by the caller's ``numpy.random.Generator``.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F


def _noise(size: int, rng: np.random.Generator, octaves: int = 4, base: int = 4) -> torch.Tensor:
    """Fractal value noise in roughly [-1, 1], (size, size)."""
    out = torch.zeros(1, 1, size, size)
    amp, total = 1.0, 0.0
    for o in range(octaves):
        cells = base * 2**o
        grid = torch.from_numpy(rng.standard_normal((1, 1, cells, cells)).astype(np.float32))
        out += amp * F.interpolate(grid, size=(size, size), mode="bicubic", align_corners=False)
        total += amp
        amp *= 0.5
    return (out / total)[0, 0]


def _colour(rng: np.random.Generator, spread: float = 0.4) -> torch.Tensor:
    return torch.from_numpy(np.exp(rng.uniform(-spread, spread, 3)).astype(np.float32)).view(3, 1, 1)


def _grid(size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel row and column coordinates, (size, size) each."""
    r = torch.arange(size, dtype=torch.float32)
    return torch.meshgrid(r, r, indexing="ij")


def _soft_rect(size: int, rng: np.random.Generator) -> torch.Tensor:
    """A rectangle (window, panel, lamp shade) in [0, 1] with edges softened by 0 to 2 pixels."""
    y, x = _grid(size)
    h, w = rng.uniform(0.1, 0.6, 2) * size
    cy, cx = rng.uniform(0, size, 2)
    soft = float(rng.uniform(0.3, 2.0))
    inside_y = torch.sigmoid((h / 2 - (y - cy).abs()) / soft)
    inside_x = torch.sigmoid((w / 2 - (x - cx).abs()) / soft)
    return inside_y * inside_x


def _light(size: int, rng: np.random.Generator) -> torch.Tensor:
    """A light source: a bright core with glare falling off as ``1 / (1 + (r / s)^2)^p``, (size, size)."""
    y, x = _grid(size)
    cy, cx = rng.uniform(-0.1, 1.1, 2) * size
    r = torch.sqrt((y - cy) ** 2 + (x - cx) ** 2)
    core = float(rng.uniform(1.0, 0.15 * size))
    p = float(rng.uniform(0.7, 2.0))
    glare = 1.0 / (1.0 + (r / core) ** 2) ** p
    disk = torch.sigmoid((core - r) / float(rng.uniform(0.3, 1.5)))
    return glare + float(rng.uniform(0.5, 5.0)) * disk


def procedural_scene(size: int, rng: np.random.Generator) -> torch.Tensor:
    """One random scene: a sky or wall gradient, shaded textured surfaces, windows and lights (3, size, size)."""
    y = torch.linspace(0, 1, size).view(size, 1).expand(size, size)
    x = torch.linspace(0, 1, size).view(1, size).expand(size, size)
    angle = rng.uniform(0, 2 * math.pi)
    ramp = math.cos(angle) * x + math.sin(angle) * y
    # background: a smooth gradient over 0 to 4 stops (sky or lit wall), tinted
    scene = _colour(rng) * torch.exp2(float(rng.uniform(0, 4)) * ramp)[None]
    # textured surfaces under multiplicative shading: albedo texture times a smooth shading field
    for _ in range(int(rng.integers(1, 4))):
        mask = _soft_rect(size, rng) if rng.random() < 0.6 else (_noise(size, rng, 2, 2) > rng.uniform(-0.3, 0.3))
        mask = mask.float()
        albedo = torch.exp(float(rng.uniform(0.1, 1.0)) * _noise(size, rng, 5, int(rng.integers(2, 16))))
        shading = torch.exp2(float(rng.uniform(-1, 4)) * (_noise(size, rng, 2, 2) + 0.5 * ramp))
        level = float(np.exp2(rng.uniform(-3, 3)))
        surface = level * _colour(rng) * (albedo * shading)[None]
        scene = scene * (1 - mask) + surface * mask
    # windows: much brighter rectangles with an outdoor gradient inside
    for _ in range(int(rng.poisson(0.8))):
        mask = _soft_rect(size, rng)
        inside = float(np.exp2(rng.uniform(2, 7))) * torch.exp2(float(rng.uniform(0, 2)) * (1 - y))
        scene = scene * (1 - mask) + _colour(rng, 0.2) * (inside * mask)[None]
    # light sources with glare (additive)
    for _ in range(int(rng.poisson(1.0))):
        scene = scene + float(np.exp2(rng.uniform(3, 9))) * _colour(rng, 0.2) * _light(size, rng)[None]
    return scene.clamp_min(1e-4).contiguous()
