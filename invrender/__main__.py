"""``python -m invrender`` (and ``torchrun ... -m invrender``): the command line."""

from invrender.cli import entry

entry()
