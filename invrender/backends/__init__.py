"""Backends: ray intersection and the compiled evaluation of the bounce (nothing above core imports them directly)."""
