"""``python -m invrender.cli``: the command line."""

from invrender.cli import entry

entry()
