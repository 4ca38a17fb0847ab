"""The ``pmba`` command line, one module per verb."""
