"""The data layer: trial logs (:class:`~vesselid.data.logs.TrialLog`), sampling checks, NMEA 0183
text,
raw-stream export, wave filtering and ingestion of raw recordings."""
