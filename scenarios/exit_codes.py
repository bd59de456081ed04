"""The command line's exit codes beyond 0 (done), 1 (a check failed) and 2 (bad input), in a module of their own so
that a command reads them without importing what uses them (``scenarios.identify`` imports the processing chain)."""

__all__ = ["EXIT_INCONSISTENT", "EXIT_METHOD_FAILED"]

EXIT_INCONSISTENT = 3  # the data are proven inconsistent with the bound (InconsistentDataError) or the spec's stated
# motion bounds (identify --spec: a qd_max / qdd_max below what the positions prove)
EXIT_METHOD_FAILED = 4  # some requested method gave no box and no proof of emptiness (result.json still written)
