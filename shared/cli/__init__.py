"""The ``linemap`` command line."""
