"""Subcommands of the ``pcvfe`` console script, one module each.

Each module defines ``register(subparsers)``, which adds its parser and sets ``func`` (called with
the parsed arguments, returning an exit code).
"""
