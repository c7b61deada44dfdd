"""Research beside the package: the measurements behind the limits and numbers in docs/, and where the default fails.

Nothing in ``torch_modulo`` imports this package. Run its scripts from the repository root as modules
(``python -m research.single_limits``); their tests are in tests/research/. README.md says what each script
measures, and what the experiments that were tried and dropped found (with the commit that holds their code).
"""
