"""The plant layer: simulated systems and vessels (model + θ0 + disturbances + sensors + inputs),
their compiled simulation, the catalogue of systems and closed-loop simulation."""
