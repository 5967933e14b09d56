"""Sub-commands of the ``torchhrc`` command line, one module each (see :mod:`torchhrc.cli`)."""
