"""Subcommands of the ``isettorch`` CLI, one module each (see ``isettorch.cli``)."""
