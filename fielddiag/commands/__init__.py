"""Sub-commands of the ``fielddiag`` CLI, one module each.

A module here defines ``register(subparsers)``, which adds its parser and sets
``func=<callable(args) -> int>`` as default. :mod:`fielddiag.cli` finds modules by name,
so adding a command is adding a file. Commands parse, call the library and print; they
hold no numerics.
"""
