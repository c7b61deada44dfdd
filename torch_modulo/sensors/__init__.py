"""Sensor adapters: simulated or real modulo cameras, all handing downstream a :class:`FrameStack`.

The same code unwraps frames whatever made them::

    stack = SimulatedModuloSensor(bits=8)(radiance, [1.0, 16.0, 256.0])   # a simulation ...
    stack = FileSensor("camera_frames/").read()                            # ... or a real camera's files
    radiance = torch_modulo.unwrap_multi(stack.moduli, stack.exposures, stack.bits)
"""

from __future__ import annotations

from torch_modulo.sensors.files import (
    IMAGE_EXTENSIONS,
    MANIFEST,
    FileSensor,
    RawFormat,
    frame_bits,
    frame_exposure,
    stack_files,
    write_frames,
)
from torch_modulo.sensors.frames import KINDS, FrameStack
from torch_modulo.sensors.simulated import (
    NoiseModel,
    SimulatedIntensitySensor,
    SimulatedModuloSensor,
    fixed_pattern_gain,
    simulate_capture,
)

__all__ = [
    "IMAGE_EXTENSIONS",
    "KINDS",
    "MANIFEST",
    "FileSensor",
    "FrameStack",
    "NoiseModel",
    "RawFormat",
    "SimulatedIntensitySensor",
    "SimulatedModuloSensor",
    "fixed_pattern_gain",
    "frame_bits",
    "frame_exposure",
    "simulate_capture",
    "stack_files",
    "write_frames",
]
