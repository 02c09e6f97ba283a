"""The bus servos' commands (``python -m tuners.bus.tune``)."""
