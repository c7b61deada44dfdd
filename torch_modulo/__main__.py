"""``python -m torch_modulo`` runs the ``torch-modulo`` command line."""

from __future__ import annotations

import sys

from torch_modulo.cli import main

sys.exit(main())
