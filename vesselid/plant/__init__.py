"""The plant layer: simulated systems and vessels (model + θ0 + disturbances + sensors + inputs),
their compiled simulation, the catalogue of systems and closed-loop simulation.

:class:`vesselid.plant.plant.Plant` is the one plant abstraction; ``System`` (heave, §5) and
``VesselModel`` (a hull in a sea) satisfy it.
"""
