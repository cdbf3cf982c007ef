"""Subcommands of `pfdoa`, one module each (see pfdoa.cli)."""
