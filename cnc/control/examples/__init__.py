"""Example control programs beside the PI-P: each improves one thing, shown by its test."""
