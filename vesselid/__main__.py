"""``python -m vesselid`` runs the command line."""

from vesselid.cli import main

raise SystemExit(main())
