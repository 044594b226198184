"""The model layer: terms of Definition 2.1, the model specification
(:class:`~vesselid.model.spec.ModelSpec`),
regressor kernels, derived signals, shipped specs and model export."""
