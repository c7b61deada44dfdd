"""Training recipes of the weights that ship in ``torch_modulo``, outside the package (as torchvision keeps its own in
``references/``). Nothing in ``torch_modulo`` imports them. Run them from the repository root as modules, e.g.
``python -m references.learned_single.train``."""
