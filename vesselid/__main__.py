"""``python -m vesselid`` runs the command line."""

from vesselid.cli.app import main

raise SystemExit(main())
