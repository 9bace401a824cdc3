"""Command-line layer (the top one): ``ramavt`` and its subcommands; nothing in the library imports it."""

from ramavt_jax.cli.main import main

__all__ = ["main"]
