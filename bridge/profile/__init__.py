"""What the signals mean: the vehicle profile model, its loader, and the expression language
of its values and rules."""
