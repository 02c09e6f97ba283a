"""The benchmark: every way of choosing gains, on every plant, as a control engineer judges."""
