"""Foundation: file and JSON I/O, lazy attributes, thread and memory settings, resource limits,
compiled helpers and the figure factory. Imports nothing else from vesselid but
:mod:`vesselid.errors`."""
