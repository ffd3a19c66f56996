"""The vehicle: the single-track model, its parameters and the multi-body truth."""
