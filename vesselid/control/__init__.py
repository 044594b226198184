"""Model-based control from an identified model."""
