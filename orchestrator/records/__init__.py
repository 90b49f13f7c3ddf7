"""A run's records on disk: rows, files, events, the output folder and its recovery.

``recorder.py`` the recorder's calls and its close, ``checks.py`` what the calls must be given, ``flusher.py``
what the callers recorded and the background thread that flushes it, ``writer.py`` what a flush writes and in
which order (write failures and consistency), ``rowstore.py`` the rows held, ``files.py`` ``trajectory.npz``
and the recording's file, ``events.py`` ``events.jsonl``, ``measured.py`` runs on measurements (no truth),
``outdir.py`` the output folder's checks and reserve, ``retention.py`` ``run.keep`` (the oldest closed segments
removed as a run until stopped goes), ``recover.py`` ``splitspec recover`` of a run cut short.
The file contracts are in docs/reference/files.md.
"""
