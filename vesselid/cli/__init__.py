"""The command line: ``vesselid <command>``; one module per plugin command."""
