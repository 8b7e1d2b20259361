"""Sub-commands of the ``kalmix`` command line, one module each."""
