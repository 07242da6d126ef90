"""Subcommands of ``leaffit-usd``: one module each (NAME, HELP, add_arguments, run)."""
