"""Research beside the package: experiments that were tried and not shipped, and the measurements behind docs.

Nothing in ``torch_modulo`` imports this package. Run its scripts from the repository root as modules
(``python -m research.single_limits``) and its tests with ``pytest research``; README.md says what each
experiment tried and what it found.
"""
